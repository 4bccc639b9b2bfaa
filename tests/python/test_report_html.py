#!/usr/bin/env python3
"""report.html (experiments/report_html.py and .js) in headless Chromium.

    test_report_html.py [DHRBENCH]

Builds report.html with experiments/report.py for a copy of reports/quick (published: no per-run
images) and, given the dhrbench binary, for a run of tests/data/tiny_experiment.json (with its
images/), opens each in headless Chromium with #selftest and checks from the page's #status
element and the browser's log: no script error or console message, every image loaded, charts
and both sortable tables drawn, and (with images) that a key press switches the viewer's image,
keeps the zoom and 'e' shows the error map. Saves screenshots in the temporary folder and
prints their paths. Exit 77 (ctest's skip code) when Chromium is not installed.
"""
import html
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

SKIP = 77
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
failures = []


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what)
    if not cond:
        failures.append(what)


def chromium(browser, url, *args):
    cmd = [browser, "--headless=new", "--disable-gpu", "--no-sandbox", "--enable-logging=stderr", "--v=0",
           "--virtual-time-budget=5000", *args, url]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    return p.stdout, p.stderr


def status_of(dom):
    m = re.search(r'<div id="status"([^>]*)>', dom)
    return {k: html.unescape(v) for k, v in re.findall(r'data-([\w-]+)="([^"]*)"', m.group(1))} if m else {}


def table_rows(dom, table_id):
    m = re.search(r'<table class="sortable" id="%s">(.*?)</table>' % table_id, dom, re.S)
    return len(re.findall(r"<tr>", m.group(1).split("<tbody>", 1)[1])) if m and "<tbody>" in m.group(1) else -1


def check_folder(folder, browser, with_images):
    name = os.path.basename(folder)
    rc = subprocess.run([sys.executable, os.path.join(REPO, "experiments", "report.py"), folder]).returncode
    check(rc == 0, f"{name}: report.py exits 0")
    page = os.path.join(folder, "report.html")
    if rc != 0 or not os.path.exists(page):
        return
    text = open(page, encoding="utf-8").read()
    check(not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text) and "<link" not in text
          and "<script src" not in text, f"{name}: self-contained (no external script, style or URL)")
    data = json.loads(re.search(r'<script type="application/json" id="data">(.*?)</script>', text, re.S)
                      .group(1))
    refs = set(re.findall(r"<img src='([^']+)'", text))
    refs |= {e[k] for v in data["viewers"] for e in v["entries"] for k in ("src", "error", "flip") if k in e}
    missing = [r for r in refs if not os.path.isfile(os.path.join(folder, r))]
    check(refs and not missing, f"{name}: the {len(refs)} images report.html references exist {missing[:3]}")
    runs = json.load(open(os.path.join(folder, "results.json")))["runs"]
    ok = [r for r in runs if "metrics" in r]

    dom, log = chromium(browser, "file://" + page + "#selftest", "--dump-dom")
    st = status_of(dom)
    console = [line for line in log.splitlines() if ":CONSOLE" in line]
    check(st.get("ready") == "1", f"{name}: the page's script ran to its end (status: {st})")
    check(st.get("errors") == "0", f"{name}: no script error ({st.get('error-messages')})")
    check(not console, f"{name}: nothing on the browser console {console[:3]}")
    loaded, expected = int(st.get("images-loaded", -1)), int(st.get("images-expected", -2))
    check(loaded == expected == len(refs) and st.get("images-failed") == "0",
          f"{name}: every image loaded ({loaded} of {expected}, {len(refs)} referenced; failed: "
          f"{st.get('images-failed-names', st.get('images-failed'))})")
    check(table_rows(dom, "runs") == len(ok), f"{name}: the runs table has one row per run ({len(ok)})")
    check(table_rows(dom, "stages") == len(ok), f"{name}: the stage table has one row per run")
    points = dom.count('class="point"')
    check(int(st.get("charts", 0)) > 0 and points > 0, f"{name}: {st.get('charts')} rate-quality charts, {points} points")
    check(st.get("sort-ok") == "true", f"{name}: clicking Mb/s sorts the runs by bitrate")
    if with_images:
        check(st.get("selftest") == "pass", f"{name}: viewer self-test: {st.get('selftest')}")
        check(st.get("src-before") != st.get("src-after") and st.get("src-after", "").endswith("_shown.png"),
              f"{name}: a key switches the image ({st.get('src-before')} -> {st.get('src-after')} -> "
              f"{st.get('src-next')}), zoom and pan kept ({st.get('transform-after')}), 'e' shows {st.get('overlay-src')}")
    else:
        check(st.get("selftest", "").startswith("pass"), f"{name}: self-test without images: {st.get('selftest')}")
    for suffix, shot in (("", "top"), ("#selftest", "selftest")):
        path = os.path.join(folder, f"screenshot_{shot}.png")
        chromium(browser, "file://" + page + suffix, f"--screenshot={path}", "--window-size=1400,1000")
        check(os.path.getsize(path) > 10000 if os.path.exists(path) else False, f"{name}: screenshot {path}")


def main():
    browser = next((shutil.which(b) for b in ("chromium", "chromium-browser", "google-chrome") if shutil.which(b)), None)
    if browser is None:
        print("SKIP: Chromium is not installed (apt-get install chromium, or scripts/setup.sh): report.html was not "
              "opened in a browser")
        return SKIP
    tmp = tempfile.mkdtemp(prefix="dhr_report_html_")
    print(f"temporary folder: {tmp}")
    quick = os.path.join(tmp, "quick")
    shutil.copytree(os.path.join(REPO, "reports", "quick"), quick)
    check_folder(quick, browser, with_images=False)
    if len(sys.argv) > 1:
        tiny = os.path.join(tmp, "tiny")
        p = subprocess.run([sys.argv[1], "run", os.path.join(REPO, "tests", "data", "tiny_experiment.json"),
                            "--out", tiny, "--no-report", "--no-disk-cache", "--threads", "2"],
                           capture_output=True, text=True, cwd=REPO)
        check(p.returncode == 0, "dhrbench run tiny_experiment.json" + (f": {p.stderr.strip()[-300:]}" if p.returncode else ""))
        if p.returncode == 0:
            check_folder(tiny, browser, with_images=True)
    else:
        print("note: no dhrbench binary given: the image viewer was not tested (reports/quick keeps no images/)")
    print(f"{len(failures)} failure(s)" if failures else "all checks passed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
