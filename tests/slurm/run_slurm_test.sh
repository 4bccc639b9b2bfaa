#!/usr/bin/env bash
# A real one-node Slurm cluster on this machine (Debian's munge, slurmctld, slurmd,
# slurm-client; scripts/setup.sh installs them), bound to 127.0.0.1, in a temporary folder,
# without systemd, as the current user (root in CI): submits tests/data/shard_experiment.json
# through scripts/slurm/submit.sh as a 2-task array plus the merge job, waits (with a time
# limit), and checks the merged results against an unsharded run in every non-timing figure
# (scripts/check_figures.py --compare). Stops every daemon it started by its process id.
#   tests/slurm/run_slurm_test.sh [DHRBENCH]     (ctest -L slurm runs it)
# Exit 0 passed, 1 failed, 77 skipped (no Slurm packages: scripts/setup.sh installs them).
# DHR_SLURM_TEST_KEEP=1 keeps the folder (logs, results) for a look.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
dhrbench=$(realpath "${1:-$root/build/experiments/dhrbench}")
limit_s=${DHR_SLURM_TEST_TIMEOUT:-180}
t0=$(date +%s.%N)

for exe in munged slurmctld slurmd sbatch squeue scontrol; do
  if ! PATH=$PATH:/usr/sbin command -v "$exe" >/dev/null; then
    echo "skipped: $exe not installed (scripts/setup.sh installs munge, slurmctld, slurmd, slurm-client)"
    exit 77
  fi
done
export PATH=$PATH:/usr/sbin
[ -x "$dhrbench" ] || { echo "FAIL: no dhrbench at $dhrbench"; exit 1; }

tmp=$(mktemp -d /tmp/dhr-slurm-test.XXXXXX)
chmod 755 "$tmp"  # munged wants the folders on its socket's path searchable by all
pids=()
cleanup() {
  local rc=$?
  for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null || true
  done
  if [ "$rc" -ne 0 ]; then
    for log in "$tmp"/log/*.log "$tmp"/out/shard.shards/logs/*.log; do
      [ -f "$log" ] && { echo "---- $log (last lines)"; tail -n 15 "$log"; }
    done
  fi
  if [ "${DHR_SLURM_TEST_KEEP:-0}" = 1 ]; then echo "kept $tmp"; else rm -rf "$tmp"; fi
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 1' INT TERM
fail() { echo "FAIL: $*"; exit 1; }

mkdir -p "$tmp"/{munge,state,spool,log,run,cache}
chmod 755 "$tmp/munge"
chmod 700 "$tmp/state" "$tmp/spool"
user=$(id -un)
host=$(hostname -s)  # slurmctld runs only where SlurmctldHost names the host
node=dhrnode        # not the host's name: slurmd is told it with -N
# Two free TCP ports on the loopback address (so that several copies of this test can run at once).
read -r ctld_port slurmd_port < <(python3 -c '
import socket
s = [socket.socket() for _ in range(2)]
for x in s: x.bind(("127.0.0.1", 0))
print(*[x.getsockname()[1] for x in s])')

# munge: a key of its own, a socket in the temporary folder.
dd if=/dev/urandom of="$tmp/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$tmp/munge/munge.key"
force=(); [ "$(id -u)" -eq 0 ] && force=(--force)
munged -F "${force[@]}" --socket="$tmp/munge/munge.socket" --key-file="$tmp/munge/munge.key" \
  --pid-file="$tmp/run/munged.pid" --log-file="$tmp/log/munged.log" --seed-file="$tmp/munge/munge.seed" \
  >"$tmp/log/munged.out" 2>&1 &
pids+=($!)

# slurm.conf: this machine's cores and memory (slurmd -C), daemons on 127.0.0.1 only.
hw=$(slurmd -C | head -1 | sed 's/^NodeName=[^ ]* //')
cpus=$(sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' <<<"$hw")
cat >"$tmp/slurm.conf" <<CONF
ClusterName=dhrtest
SlurmctldHost=$host(127.0.0.1)
SlurmUser=$user
SlurmdUser=$user
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
CommunicationParameters=NoCtldInAddrAny,NoInAddrAny
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$tmp/munge/munge.socket
StateSaveLocation=$tmp/state
SlurmdSpoolDir=$tmp/spool
SlurmctldPidFile=$tmp/run/slurmctld.pid
SlurmdPidFile=$tmp/run/slurmd.pid
SlurmctldLogFile=$tmp/log/slurmctld.log
SlurmdLogFile=$tmp/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
MailProg=/bin/true
MessageTimeout=5
SlurmdTimeout=30
MinJobAge=600
NodeName=$node NodeAddr=127.0.0.1 NodeHostname=$(hostname) $hw State=UNKNOWN
PartitionName=dhrtest Nodes=$node Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF=$tmp/slurm.conf

for _ in $(seq 50); do [ -S "$tmp/munge/munge.socket" ] && break; sleep 0.1; done
[ -S "$tmp/munge/munge.socket" ] || fail "munged did not start"
t_daemons=$(date +%s.%N)
slurmctld -D -f "$tmp/slurm.conf" >"$tmp/log/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -N "$node" -f "$tmp/slurm.conf" >"$tmp/log/slurmd.out" 2>&1 &
pids+=($!)
alive() { for pid in "${pids[@]}"; do kill -0 "$pid" 2>/dev/null || fail "a daemon (pid $pid) stopped"; done; }
up=0
deadline=$(( $(date +%s) + 30 ))
while [ "$(date +%s)" -lt "$deadline" ]; do
  alive
  if timeout 5 sinfo -h -N -o '%T' 2>/dev/null | grep -Eq '^(idle|mixed|allocated)'; then up=1; break; fi
  sleep 0.1
done
[ "$up" = 1 ] || fail "the cluster did not come up in 30 s: $(sinfo -N 2>&1 | tail -2)"
t_up=$(date +%s.%N)

# Submit: 2 shards with 1 core each, a shared cache in the temporary folder.
exp=$root/tests/data/shard_experiment.json
submitted=$(cd "$tmp" && "$root/scripts/slurm/submit.sh" "$exp" --shards 2 --cpus 1 --mem 500M --time 10 \
  --partition dhrtest --cache "$tmp/cache" --out "$tmp/out/shard" --dhrbench "$dhrbench")
echo "$submitted"
array=$(sed -n 's/^array job \([0-9]*\):.*/\1/p' <<<"$submitted")
merge=$(sed -n 's/^merge job \([0-9]*\):.*/\1/p' <<<"$submitted")
[ -n "$array" ] && [ -n "$merge" ] || fail "submit.sh printed no job ids"
# The merge job depends on the array.
scontrol show job "$merge" | grep -q "Dependency=afterok:${array}" || fail "merge job $merge has no afterok:$array dependency"

state() { timeout 10 scontrol show job "$1" 2>/dev/null | sed -n 's/.*JobState=\([A-Z_]*\).*/\1/p' | head -1; }
wait_for() {
  local s deadline=$(( $(date +%s) + limit_s ))
  while :; do
    s=$(state "$1")
    case "$s" in COMPLETED) break ;; FAILED|CANCELLED|TIMEOUT|NODE_FAIL|OUT_OF_MEMORY) fail "job $1: $s" ;; esac
    [ "$(date +%s)" -lt "$deadline" ] || fail "job $1 did not finish in ${limit_s} s (state: ${s:-unknown})"
    alive
    sleep 0.2
  done
}
wait_for "$merge"
t_done=$(date +%s.%N)
for task in 1 2; do
  s=$(state "${array}_$task")
  [ "$s" = COMPLETED ] || fail "array task ${array}_$task: ${s:-unknown}"
  grep -q "shard $task/2 of .* 1 cores" "$tmp/out/shard.shards/logs/shard_$task.log" || fail "task $task did not get 1 core"
done

# The same experiment unsharded, outside Slurm, with a cache of its own.
DHR_CACHE_DIR=$tmp/cache_whole "$dhrbench" run "$exp" --out "$tmp/out/whole" --no-report 2>/dev/null
python3 "$root/scripts/check_figures.py" --compare "$tmp/out/shard" "$tmp/out/whole" || fail "merged results differ"
[ -f "$tmp/out/shard/report.md" ] || fail "the merge job wrote no report"
python3 - "$tmp/out/shard/results.json" "$tmp/out/whole/results.json" <<'PY' || fail "run order or records differ"
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
assert [r["id"] for r in a["runs"]] == [r["id"] for r in b["runs"]], "run order"
assert len(a["shards"]) == 2, "shards"
PY

# A lost shard is rerun alone (submit.sh --only) and merged again.
rm -rf "$tmp/out/shard.shards/2" "$tmp/out/shard"
submitted=$(cd "$tmp" && "$root/scripts/slurm/submit.sh" "$exp" --shards 2 --only 2 --cpus 1 --mem 500M --time 10 \
  --partition dhrtest --cache "$tmp/cache" --out "$tmp/out/shard" --dhrbench "$dhrbench")
echo "$submitted"
grep -q "shards 2 of 2" <<<"$submitted" || fail "--only 2 did not submit shard 2 alone"
wait_for "$(sed -n 's/^merge job \([0-9]*\):.*/\1/p' <<<"$submitted")"
python3 "$root/scripts/check_figures.py" --compare "$tmp/out/shard" "$tmp/out/whole" || fail "merged results after the rerun differ"
t_end=$(date +%s.%N)

# Measurement (not part of the test): DHR_SLURM_MEASURE="1 2 4" submits
# DHR_SLURM_MEASURE_EXPERIMENT as that many shards in turn (cores per task: the node's cores
# divided by the shards, at least 1; each with a cold cache) and prints the wall time from
# submission to the merged report, and each job's own run time.
if [ -n "${DHR_SLURM_MEASURE:-}" ]; then
  mexp=$(realpath "${DHR_SLURM_MEASURE_EXPERIMENT:?the experiment to measure}")
  for n in $DHR_SLURM_MEASURE; do
    c=$(( cpus / n )); [ "$c" -ge 1 ] || c=1
    m0=$(date +%s.%N)
    submitted=$(cd "$tmp" && "$root/scripts/slurm/submit.sh" "$mexp" --shards "$n" --cpus "$c" --mem 2G --time 60 \
      --partition dhrtest --cache "$tmp/mcache$n" --out "$tmp/measure/n$n" --dhrbench "$dhrbench")
    mid=$(sed -n 's/^merge job \([0-9]*\):.*/\1/p' <<<"$submitted")
    limit_s=3600 wait_for "$mid"
    m1=$(date +%s.%N)
    shard_walls=$(python3 - "$tmp/measure/n$n/results.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
print(" ".join("%.1f" % s["wall_s"] for s in r["shards"]))
PY
)
    awk -v a="$m0" -v b="$m1" -v n="$n" -v c="$c" -v w="$shard_walls" 'BEGIN {
      printf "measure: %d shard(s), %d core(s) each: %.1f s from submission to the merged report; shards ran %s s\n", n, c, b - a, w }'
  done
fi
awk -v a="$t0" -v d="$t_daemons" -v u="$t_up" -v j="$t_done" -v e="$t_end" 'BEGIN {
  printf "slurm test passed: cluster up %.1f s after its daemons started; jobs (2 shards + merge) %.1f s; whole test %.1f s\n", u - d, j - u, e - a }'
