"""DIR/report.html beside report.md: one static file (inline CSS and JavaScript, no network) that
opens in any browser from the folder itself. The answer-first header of report.md; sortable
tables of the runs and their stage times; rate-quality curves drawn as SVG by
experiments/report_html.js (tooltips, log bitrate axis, one chart per scene and condition, FLIP
first); per scene an image viewer over images/ (ground truth, local reference, each run's
displayed frame; keys 1-9 and arrows switch, wheel zooms, drag pans, 'e' overlays the error map
and then FLIP's); and the PNGs of plots/ and grids/. Images are referenced relatively, so the
folder moves as a whole. Opening DIR/report.html#selftest makes the page exercise the viewer and
a table sort and record the outcome in its #status element (tests/python/test_report_html.py).
"""
import html
import json
import os
import re

import rate_quality as rq

HERE = os.path.dirname(os.path.abspath(__file__))
LEADING = ("flip", "ssim", "psnr")  # metric order: FLIP first, then the others as declared


def ordered_metrics(metrics):
    return sorted(metrics, key=lambda im: LEADING.index(im["name"]) if im["name"] in LEADING else len(LEADING))


def _inline(text):
    """Markdown inline markup of report.md's lines (code, bold, italics, links) as HTML."""
    parts = re.split(r"(`[^`]*`)", text)
    out = []
    for p in parts:
        if len(p) >= 2 and p.startswith("`") and p.endswith("`"):
            out.append(f"<code>{html.escape(p[1:-1])}</code>")
            continue
        s = html.escape(p, quote=False)
        s = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", s)
        s = re.sub(r"(?<![\w*])\*(?!\s)(.+?)\*(?![\w*])", r"<i>\1</i>", s)
        s = re.sub(r"\[([^\]]+)\]\(([^)\s]+)\)", lambda m: f'<a href="{m.group(2).replace(chr(34), "&quot;")}">{m.group(1)}</a>', s)
        out.append(s)
    return "".join(out)


def markdown_lines(lines):
    """report.md's section lines (headings, paragraphs, tables, bullets, images) as HTML."""
    out, table = [], []

    def flush():
        if table:
            rows = [[c.strip() for c in row.strip().strip("|").split("|")] for row in table
                    if not re.fullmatch(r"\|?[-| :]+\|?", row.strip())]
            out.append("<table class='md'>" + "".join(
                "<tr>" + "".join(f"<{'th' if i == 0 else 'td'}>{_inline(c)}</{'th' if i == 0 else 'td'}>" for c in r)
                + "</tr>" for i, r in enumerate(rows)) + "</table>")
            table.clear()

    for block in "\n".join(lines).split("\n"):
        line = block.rstrip()
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if not line:
            continue
        m = re.match(r"(#{1,4}) (.*)", line)
        img = re.fullmatch(r"!\[([^\]]*)\]\(([^)]+)\)", line)
        if m:
            n = len(m.group(1))
            out.append(f"<h{n}>{_inline(m.group(2))}</h{n}>")
        elif img:
            out.append(f"<img src='{html.escape(img.group(2))}' alt='{html.escape(img.group(1))}'>")
        elif line.startswith("- "):
            out.append(f"<ul><li>{_inline(line[2:])}</li></ul>")
        else:
            out.append(f"<p>{_inline(line)}</p>")
    flush()
    return "\n".join(out)


def _num(v, digits):
    if v is None or not isinstance(v, (int, float)):
        return "<td data-v=''>–</td>"
    return f"<td data-v='{v!r}'>{v:.{digits}f}</td>"


def _setting(v):
    return v if isinstance(v, str) else json.dumps(v, separators=(",", ":"), sort_keys=True)


def conditions(run):
    return ", ".join(f"{k}={_setting(v)}" for k, v in sorted(run.get("settings", {}).items()))


def runs_table(ok, metrics):
    ims = ordered_metrics(metrics)
    head = ["run", "scene", "configuration", "family", "mode", "conditions", "Mb/s"]
    head += [f"{im['name'].upper().replace('_', ' ')} {'truth' if ref == 'ground_truth' else 'local'}"
             + (f" ({'↑' if im['higher_is_better'] else '↓'})") for im in ims for ref in ("ground_truth", "local")]
    rows = []
    for r in ok:
        m = r["metrics"]
        cells = [f"<td>{html.escape(str(x))}</td>" for x in
                 (r["id"], r["scene"], r.get("configuration", r["label"]), rq.family_of(r),
                  r.get("config", {}).get("mode", "hybrid"), conditions(r))]
        cells.append(_num(m.get("bandwidth_mbps"), 3))
        for im in ims:
            for ref in ("ground_truth", "local"):
                cells.append(_num(m.get(im["aggregates"][ref]["mean"]), 2 if im["unit"] else 4))
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return ("<div class='wide'><table class='sortable' id='runs'><thead><tr>" + "".join(
        f"<th>{html.escape(h)}</th>" for h in head) + "</tr></thead><tbody>" + "\n".join(rows) + "</tbody></table></div>")


def stages_table(ok):
    names = []
    for r in ok:
        names += [s for s in r["metrics"]["stages_wall"] if s not in names]
    rows = []
    for r in ok:
        st = r["metrics"]["stages_wall"]
        rows.append(f"<tr><td>{html.escape(r['id'])}</td>" + "".join(
            _num(st[s]["median_ms"], 2) if s in st else "<td data-v=''>–</td>" for s in names) + "</tr>")
    return ("<div class='wide'><table class='sortable' id='stages'><thead><tr><th>run</th>" + "".join(
        f"<th>{html.escape(s)}</th>" for s in names) + "</tr></thead><tbody>" + "\n".join(rows) + "</tbody></table></div>")


def chart_data(exp, ok, metrics, quality):
    """Per metric, one chart per (scene, conditions): the families' points (rate_quality.curves,
    grouped as report.md's rate-quality section where the experiment declares "curves"; else each
    setting of the experiment's "sweep" that differs between runs is a condition and each
    configuration one point)."""
    spec = exp.get("curves") if isinstance(exp.get("curves"), dict) else None
    vary = [k for k in (spec or {}).get("vary", []) if isinstance(k, str)]
    if spec is not None:
        sweep_keys = sorted({k for r in ok for k in r.get("settings", {}) if k not in vary})
    else:
        sweep = exp.get("sweep") if isinstance(exp.get("sweep"), dict) else {}
        sweep_keys = sorted(k for k in sweep if len({_setting(r.get("settings", {}).get(k)) for r in ok}) > 1)
    anchor = (spec or {}).get("anchor")
    anchors = [anchor] if isinstance(anchor, str) else [a for a in (anchor or []) if isinstance(a, str)]
    out = []
    for im in ordered_metrics(metrics):
        cm = rq.curves(ok, sweep_keys, vary, lambda r: r["metrics"]["bandwidth_mbps"] or None,
                       lambda r, im=im: quality(r, im))
        charts = {}
        for (scene, cond, fam), pts in sorted(cm.items()):
            chart = charts.setdefault((scene, cond), {"scene": scene, "cond": ", ".join(f"{k}={v}" for k, v in cond)
                                                      or "all runs", "series": []})
            chart["series"].append({"family": fam, "anchor": fam in anchors, "points": [
                {"x": float(f"{x:.6g}"), "y": float(f"{y:.6g}"), "id": r["id"], "conf": r.get("configuration", r["label"]),
                 "ref": "truth" if r["metrics"].get(im["aggregates"]["ground_truth"]["mean"]) is not None else "local"}
                for x, y, r in pts]})
        if charts:
            out.append({"metric": im["name"], "unit": im["unit"], "higher": im["higher_is_better"],
                        "charts": list(charts.values())})
    return out


def viewer_data(d, ok):
    """Per scene, the images of images/ that exist: the first run's ground truth and local
    reference, then each run's displayed frame with its error map and FLIP map."""
    have = lambda name: os.path.exists(os.path.join(d, "images", name))  # noqa: E731
    scenes = []
    for scene in sorted({r["scene"] for r in ok}):
        rs = [r for r in ok if r["scene"] == scene and have(r["id"] + "_shown.png")]
        if not rs:
            continue
        first = rs[0]["id"]
        entries = []
        if have(first + "_truth.png"):
            entries.append({"name": f"ground truth ({first})", "src": f"images/{first}_truth.png"})
        if have(first + "_local.png"):
            entries.append({"name": f"local reference ({first})", "src": f"images/{first}_local.png"})
        for r in rs:
            e = {"name": f"{r['id']}: {r.get('configuration', r['label'])}", "src": f"images/{r['id']}_shown.png",
                 "against": r.get("images", {}).get("error_against", "reference"),
                 "mbps": r["metrics"]["bandwidth_mbps"]}
            for kind in ("error", "flip"):
                if have(f"{r['id']}_{kind}.png"):
                    e[kind] = f"images/{r['id']}_{kind}.png"
            entries.append(e)
        scenes.append({"scene": scene, "entries": entries})
    return scenes


def figures(d):
    """The PNGs of plots/ and grids/ (what report.md shows), as static images."""
    out = []
    for sub in ("plots", "grids"):
        folder = os.path.join(d, sub)
        names = sorted(n for n in os.listdir(folder) if n.endswith(".png")) if os.path.isdir(folder) else []
        out += [f"<figure><img src='{sub}/{html.escape(n)}' alt='{html.escape(n)}'><figcaption>{sub}/"
                f"{html.escape(n)}</figcaption></figure>" for n in names]
    return "\n".join(out)


CSS = """
body{font:14px/1.4 system-ui,sans-serif;margin:1em 2em;color:#222;max-width:1600px}
h1{font-size:1.6em}h2{margin-top:1.6em;border-bottom:1px solid #ccc}
code{background:#f3f3f3;padding:0 .2em}
.wide{overflow-x:auto}
table{border-collapse:collapse;margin:.5em 0;font-size:12px}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:left}
td[data-v]{text-align:right}
table.sortable th{cursor:pointer;background:#eef;user-select:none}
th.asc:after{content:' ▲'}th.desc:after{content:' ▼'}
.charts{display:flex;flex-wrap:wrap;gap:12px}
.chart{border:1px solid #ddd;padding:4px}.chart svg{display:block}
.legend{font-size:11px;max-width:420px}.legend span{display:inline-block;margin-right:8px}
.viewer{margin:1em 0;border:1px solid #ccc;padding:6px}
.viewer.active{border-color:#36c}
.vbuttons button{margin:2px;font-size:12px}.vbuttons button.on{background:#36c;color:#fff}
.viewport{position:relative;overflow:hidden;width:100%;height:70vh;background:#333;cursor:grab}
.viewport img{position:absolute;left:0;top:0;transform-origin:0 0;image-rendering:pixelated}
.viewport img.overlay{display:none}.viewport.showov img.overlay{display:block}
.vinfo{font-size:12px;color:#444;margin:3px 0}
figure{display:inline-block;margin:6px}figure img{max-width:100%}
#status{font-size:11px;color:#888}
"""


def write(d, header_lines, res, ok, failed, metrics, quality):
    """Writes d/report.html. header_lines: report.md's answer-first lines (markdown);
    quality(run, image metric): the figure the curves use (report.metric_value)."""
    with open(os.path.join(HERE, "report_html.js"), encoding="utf-8") as f:
        script = f.read()
    data = {"charts": chart_data(res["experiment"], ok, metrics, quality), "viewers": viewer_data(d, ok)}
    data_json = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    failed_html = "".join(f"<li>{html.escape(r['id'])} ({html.escape(r['label'])} on {html.escape(r['scene'])}): "
                          f"<code>{html.escape(r['error'])}</code></li>" for r in failed)
    name = html.escape(res["experiment"].get("name", "experiment"))
    body = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{name}: dhrbench report</title>
<style>{CSS}</style></head><body>
<div id="status" data-errors="0" data-error-messages="" data-images-loaded="0" data-images-failed="0"
 data-images-expected="0" data-charts="0" data-selftest="not run"></div>
{markdown_lines(header_lines)}
<p>This page: rate-quality charts (hover a point), report.md's figures as sortable tables (click a heading),
one image viewer per scene and the report's plots. The full text with its BD-rate tables is in
<a href="report.md">report.md</a>.</p>
<h2>Rate-quality</h2>
<p>One chart per scene and condition; each family's runs joined in order of bitrate (log axis). Quality: against
the ground truth where the run scored it, else the local reference. Metric: <select id="metric"></select></p>
<div class="charts" id="charts"></div>
<h2>Runs</h2>
<p>Quality: each metric's mean over the scored frames against the ground truth (truth) and the local reference
(local); ↑ higher is better, ↓ lower. Mb/s: every packet on the wire.</p>
{runs_table(ok, metrics)}
{f"<h3>Failed runs</h3><ul>{failed_html}</ul>" if failed else ""}
<h2>Images</h2>
<p>Per scene the last scored frame, at the size the run stored in images/. Keys: 1-9 or ←/→ switch (or click a
button); wheel zooms, drag pans (kept when switching); <b>e</b> shows the run's error map (|luma difference|
0..32 levels as black..white), then FLIP's map, then the frame; <b>0</b> resets the view. Keys go to the viewer
last clicked or hovered.</p>
<div id="viewers"></div>
<h2>Stage wall times (median ms)</h2>
{stages_table(ok)}
<h2>Plots and grids</h2>
{figures(d)}
<script type="application/json" id="data">{data_json}</script>
<script>{script}</script>
</body></html>
"""
    with open(os.path.join(d, "report.html"), "w", encoding="utf-8") as f:
        f.write(body)
