#!/usr/bin/env bash
# Live mode on one machine: dhrbench serve, relay and client over loopback UDP, then a summary.
#   bash scripts/live_loopback.sh [OUT_DIR] [settings for both sides, e.g. --set width=640]
# (client-only options go in DHR_LIVE_CLIENT_ARGS, e.g. "--save-every 0 --score-every 30")
# Environment:
#   DHR_LIVE_SCENE     scene (default room)
#   DHR_LIVE_FRAMES    frames the client displays (default 300: 5 s at 60 Hz)
#   DHR_LIVE_DOWNLINK  relay downlink JSON (default: 20 ms +- 5 ms normal latency, reordering
#                      allowed, 1 % independent loss); DHR_LIVE_UPLINK (default 20 ms)
#   DHR_LIVE_NO_RELAY=1  client straight to the server
#   DHR_LIVE_KEY_FILE  a key file for both sides: every datagram authenticated (HMAC-SHA256;
#                      docs/live-security.md); e.g. head -c 32 /dev/urandom > out/live.key
# Needs a built ./build/experiments/dhrbench (bash scripts/build.sh build).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
exe=${DHRBENCH:-$root/build/experiments/dhrbench}
[ -x "$exe" ] || { echo "live_loopback: $exe not found: build first (bash scripts/build.sh build)" >&2; exit 1; }
out=${1:-out/live}
shift || true
scene=${DHR_LIVE_SCENE:-room}
frames=${DHR_LIVE_FRAMES:-300}
downlink=${DHR_LIVE_DOWNLINK:-'{"latency": "normal", "latency_ms": 20, "jitter_ms": 5, "preserve_order": false, "loss": "independent", "loss_rate": 0.01}'}
uplink=${DHR_LIVE_UPLINK:-'{"latency_ms": 20}'}
key=()
[ -n "${DHR_LIVE_KEY_FILE:-}" ] && key=(--key-file "$DHR_LIVE_KEY_FILE")
mkdir -p "$out"
rm -f "$out/server.port" "$out/relay.port"
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; }
trap cleanup EXIT

wait_port() {  # file, seconds, pid, log
  for _ in $(seq $(( $2 * 10 ))); do
    [ -s "$1" ] && { cat "$1"; return 0; }
    kill -0 "$3" 2>/dev/null || { echo "live_loopback: the process writing $1 exited:" >&2; cat "$4" >&2; return 1; }
    sleep 0.1
  done
  echo "live_loopback: no port in $1 after $2 s" >&2; return 1
}

"$exe" serve --scene "$scene" "$@" "${key[@]}" --bind 127.0.0.1:0 --port-file "$out/server.port" --out "$out/server" \
  >"$out/server.log" 2>&1 &
pids+=($!)
port=$(wait_port "$out/server.port" 120 "${pids[0]}" "$out/server.log")
target=127.0.0.1:$port
if [ "${DHR_LIVE_NO_RELAY:-0}" != 1 ]; then
  "$exe" relay --listen 127.0.0.1:0 --server "$target" --port-file "$out/relay.port" --out "$out/relay.json" \
    --downlink "$downlink" --uplink "$uplink" >"$out/relay.log" 2>&1 &
  pids+=($!)
  target=127.0.0.1:$(wait_port "$out/relay.port" 30 "${pids[1]}" "$out/relay.log")
fi
# shellcheck disable=SC2086
"$exe" client --scene "$scene" "$@" "${key[@]}" --server "$target" --frames "$frames" --out "$out/client" ${DHR_LIVE_CLIENT_ARGS:-} 2>&1 | tee "$out/client.log"
wait "${pids[@]}" 2>/dev/null || true
pids=()
cat "$out/server.log"
[ -f "$out/relay.log" ] && cat "$out/relay.log"
echo "live_loopback: results in $out/client/live.json, $out/server/, $out/relay.json"
