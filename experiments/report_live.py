#!/usr/bin/env python3
"""Writes DIR/report.md of a live-mode run (scripts/live_loopback.sh DIR: `dhrbench serve`,
`relay` and `client` over loopback UDP) from what the three processes wrote: client/live.json,
server/server.json and relay.json. Every figure in it comes from those files.

    /usr/bin/python3 experiments/report_live.py reports/live
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import dhrbench_results as dr  # noqa: E402


def build(d):
    live = dr.load_live(d)
    c, ss, r = live.client, live.session, live.relay
    cpath, spath, rpath = live.client_path, live.server_path, live.relay_path
    C = lambda p: dr.number(c, p, cpath)  # noqa: E731
    S = lambda p: dr.number(ss, p, spath + ": sessions[0]")  # noqa: E731
    R = lambda p: dr.number(r, p, rpath)  # noqa: E731
    offer = dr.field(c, "offer", cpath)
    passes = sorted(dr.field(c, "passes", cpath))

    def link(name):
        x, where = dr.field(r, name, rpath), rpath + ": " + name
        parts = [f"{dr.field(x, 'latency', where)} latency {dr.number(x, 'latency_ms', where):g} ms"]
        if dr.number(x, "jitter_ms", where):
            parts.append(f"± {x['jitter_ms']:g} ms")
        if dr.field(x, "loss", where) != "none":
            parts.append(f"{x['loss']} loss {100 * dr.number(x, 'loss_rate', where):g} %")
        if not x.get("preserve_order", True):
            parts.append("reordering")
        return " ".join(parts)

    codecs = ", ".join(f"{p} {offer.get(p + '_codec', {}).get('name')}" for p in passes)
    denoisers = ", ".join(f"{p} {offer.get(p + '_denoiser', {}).get('name')}" for p in passes)
    predictors = ", ".join(f"{p} {dr.field(c, 'predictor.' + p + '.name', cpath)}" for p in passes)
    q = lambda m, k: C(f"quality.{m}.{k}")  # noqa: E731
    saved = live.saved_frames
    ages = [C(f"passes.{p}.age_ms.median") for p in passes]
    out = [
        "# Live mode on loopback: server, relay and client as three processes\n",
        "## The answer\n",
        "Question: over real UDP sockets, through a relay that delays and loses datagrams, does the client keep up "
        "with its display, and at what quality?\n",
        f"- {C('frames.displayed'):.0f} of {C('frames.requested'):.0f} frames displayed on time "
        f"({C('frames.skipped_late'):.0f} missed their display time), showing passes "
        f"{f'{min(ages):.0f}' if round(min(ages)) == round(max(ages)) else f'{min(ages):.0f}-{max(ages):.0f}'} ms old "
        f"(median); {C('socket.mbps'):.2f} Mb/s on the wire, {100 * C('packets.loss_rate'):.2f} % of the packets "
        f"lost; against the local reference SSIM {q('ssim_local', 'mean'):.3f} and FLIP {q('flip_local', 'mean'):.3f} "
        f"(means over {C('frames.scored'):.0f} scored frames).\n",
        f"Scale: {offer.get('width')}x{offer.get('height')}, scene {offer.get('scene')}, one run of "
        f"{C('socket.duration_s'):.1f} s of wall clock on one machine (three processes sharing its cores).\n",
    ] + ([f"![the client's frame {saved[-1]}](client/frames/{saved[-1]})\n"] if saved else []) + [
        "## The run\n",
        "Written by `/usr/bin/python3 experiments/report_live.py reports/live` from the files beside it; made by "
        "`DHR_LIVE_CLIENT_ARGS=\"--save-every 300\" DHR_LIVE_FRAMES=600 bash scripts/live_loopback.sh reports/live` "
        "(what `bash scripts/regenerate_reports.sh` runs for it). Wall-clock results: the three processes share the "
        "machine's cores, and a second run gives other numbers.\n",
        f"Scene {offer.get('scene')}, {offer.get('width')}x{offer.get('height')}, {offer.get('display_hz'):g} Hz; "
        f"codecs: {codecs}; denoisers: {denoisers}; predictors: {predictors}. Relay downlink: {link('downlink')}; "
        f"uplink: {link('uplink')}. Authentication: {c.get('authentication')}.\n",
        "| measure | value |", "| --- | --- |",
        f"| frames displayed | {C('frames.displayed'):.0f} of {C('frames.requested'):.0f} "
        f"({C('frames.skipped_late'):.0f} skipped: the client missed their display time); "
        f"{C('frames.without_data'):.0f} before the first data arrived |",
        f"| client work per frame (rasterize, decode, predict, composite) | median {C('client_ms.median'):.1f} ms, "
        f"p95 {C('client_ms.p95'):.1f} ms |",
        f"| socket (client) | {C('socket.mbps'):.2f} Mb/s on the wire (28 B IP/UDP per datagram counted), "
        f"{C('socket.datagrams_per_s'):.0f} datagrams/s, {C('socket.session_bytes') / 1e6:.2f} MB of UDP payload in "
        f"{C('socket.duration_s'):.1f} s |",
        f"| packet loss seen by the receiver | {C('packets.lost'):.0f} packets ({100 * C('packets.loss_rate'):.2f} %); "
        f"the relay dropped {R('server_to_client.dropped_loss'):.0f} of {R('server_to_client.received'):.0f} downlink "
        "datagrams |",
        "| pass frames completed / lost | " + "; ".join(
            f"{p} {C(f'passes.{p}.frames_completed'):.0f} / {C(f'passes.{p}.frames_lost'):.0f}" for p in passes) + " |",
        "| buffer age at display (median, p95) | " + "; ".join(
            f"{p} {C(f'passes.{p}.age_ms.median'):.0f} ms, {C(f'passes.{p}.age_ms.p95'):.0f} ms" for p in passes) + " |",
        "| camera sent to pass complete (median, p95) | " + "; ".join(
            f"{p} {C(f'passes.{p}.round_trip_ms.median'):.1f} ms, {C(f'passes.{p}.round_trip_ms.p95'):.1f} ms"
            for p in passes) + " |",
        f"| quality against the local reference ({C('frames.scored'):.0f} frames scored) | SSIM mean "
        f"{q('ssim_local', 'mean'):.3f} (median {q('ssim_local', 'median'):.3f}); PSNR mean {q('psnr_local_db', 'mean'):.1f} dB; "
        f"FLIP mean {q('flip_local', 'mean'):.3f} (p95 {q('flip_local', 'p95'):.3f}); temporal error mean "
        f"{q('temporal_error_local_levels', 'mean'):.2f} luma levels, static flicker {q('static_flicker_local_levels', 'mean'):.2f} |",
        f"| server | {S('frames_served'):.0f} frames served in {S('duration_s'):.1f} s (compute median "
        f"{S('compute_ms.median'):.1f} ms, p95 {S('compute_ms.p95'):.1f} ms); {S('cameras_superseded'):.0f} cameras "
        f"superseded while it was busy; {S('datagrams_sent'):.0f} datagrams, {S('bytes_sent') / 1e6:.2f} MB sent, "
        f"{S('datagrams_dropped_by_send_buffer'):.0f} refused by the send buffer |",
        "",
        "The server serves only the newest camera it holds: a camera that arrives while it is busy supersedes the "
        "one before. The round trip is the relay's latency both ways plus the server's compute plus the wait for the "
        "next camera; it is what the client's reprojection hides. Compare the simulator's latency sweep in "
        "`reports/latency_loss`.\n",
        "Files: `client/live.json` (the client's summary), `client/frames.csv` (per displayed frame), "
        "`client/socket.csv` (per second), `client/received_passes.csv` (per completed pass), `client/frames/` "
        "(saved frames), `server/server.json`, `server/server_frames.csv` (per frame and pass), `relay.json`, and "
        "each side's log.",
    ]
    return "\n".join(out) + "\n"


def main(argv):
    if len(argv) != 2:
        sys.exit("usage: report_live.py DIR   (the folder scripts/live_loopback.sh wrote)")
    try:
        text = build(argv[1])
    except dr.BadResults as e:
        print(f"report_live: error: {e}", file=sys.stderr)
        return 2
    with open(os.path.join(argv[1], "report.md"), "w") as f:
        f.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
