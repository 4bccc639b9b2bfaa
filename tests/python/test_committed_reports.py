"""Every committed report.md is what experiments/report.py writes from the report's own results
(so no figure in its prose can go stale), and reports/README.md is what
experiments/report_index.py writes from them. A report is rebuilt in a scratch copy of its
results.json, frames.csv(.gz) and grids/; a difference fails with the diff and the command that
refreshes the committed file."""
import difflib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
REPORTS = os.path.join(ROOT, "reports")
REPORT_PY = os.path.join(ROOT, "experiments", "report.py")
try:
    import matplotlib  # noqa: F401
except ImportError:
    matplotlib = None


def committed():
    return sorted(n for n in os.listdir(REPORTS) if os.path.exists(os.path.join(REPORTS, n, "results.json")))


class CommittedReports(unittest.TestCase):
    def test_there_are_reports(self):
        # A test over an empty list would pass by finding nothing.
        self.assertGreaterEqual(len(committed()), 5)

    @unittest.skipIf(matplotlib is None, "python3-matplotlib is not installed (scripts/setup.sh)")
    def test_report_md_regenerates_identically(self):
        with tempfile.TemporaryDirectory() as tmp:
            for name in committed():
                with self.subTest(report=name):
                    src, dst = os.path.join(REPORTS, name), os.path.join(tmp, name)
                    os.makedirs(dst)
                    for f in ("results.json", "frames.csv", "frames.csv.gz"):
                        if os.path.exists(os.path.join(src, f)):
                            shutil.copy(os.path.join(src, f), dst)
                    if os.path.isdir(os.path.join(src, "grids")):
                        shutil.copytree(os.path.join(src, "grids"), os.path.join(dst, "grids"))
                    p = subprocess.run([sys.executable, REPORT_PY, dst], capture_output=True, text=True,
                                       cwd=os.path.join(ROOT, "experiments"))
                    self.assertEqual(p.returncode, 0, p.stderr)
                    with open(os.path.join(src, "report.md")) as f:
                        have = f.read()
                    with open(os.path.join(dst, "report.md")) as f:
                        written = f.read()
                    if have != written:
                        diff = "".join(list(difflib.unified_diff(have.splitlines(True), written.splitlines(True),
                                                                 f"reports/{name}/report.md", "written"))[:40])
                        self.fail(f"reports/{name}/report.md differs from what its results give "
                                  f"(refresh: dhrbench report reports/{name}):\n{diff}")

    def test_live_report_regenerates_identically(self):
        # reports/live is written by experiments/report_live.py from the three processes' files.
        with tempfile.TemporaryDirectory() as tmp:
            dst = os.path.join(tmp, "live")
            shutil.copytree(os.path.join(REPORTS, "live"), dst)
            os.remove(os.path.join(dst, "report.md"))
            p = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "report_live.py"), dst],
                               capture_output=True, text=True)
            self.assertEqual(p.returncode, 0, p.stderr)
            with open(os.path.join(REPORTS, "live", "report.md")) as a, open(os.path.join(dst, "report.md")) as b:
                self.assertEqual(a.read(), b.read(), "refresh: /usr/bin/python3 experiments/report_live.py reports/live")
            # A damaged file is one line naming it and the field.
            with open(os.path.join(dst, "relay.json")) as f:
                relay = json.load(f)
            del relay["server_to_client"]
            with open(os.path.join(dst, "relay.json"), "w") as f:
                json.dump(relay, f)
            p = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "report_live.py"), dst],
                               capture_output=True, text=True)
            self.assertEqual(p.returncode, 2)
            self.assertIn("relay.json: server_to_client.dropped_loss: missing", p.stderr)
            self.assertNotIn("Traceback", p.stderr)

    def test_index_is_current(self):
        p = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "report_index.py"), "--check"],
                           capture_output=True, text=True)
        self.assertEqual(p.returncode, 0, p.stdout[-4000:] + p.stderr)

    def test_index_check_sees_a_stale_line(self):
        # The check itself can fail: a copy of the tree whose index lost a line is reported stale.
        with tempfile.TemporaryDirectory() as tmp:
            shutil.copytree(os.path.join(ROOT, "experiments"), os.path.join(tmp, "experiments"),
                            ignore=shutil.ignore_patterns("__pycache__"))
            os.makedirs(os.path.join(tmp, "reports"))
            for name in ("quick", "converge"):
                shutil.copytree(os.path.join(REPORTS, name), os.path.join(tmp, "reports", name))
            script = os.path.join(tmp, "experiments", "report_index.py")
            self.assertEqual(subprocess.run([sys.executable, script], capture_output=True).returncode, 0)
            readme = os.path.join(tmp, "reports", "README.md")
            with open(readme) as f:
                lines = f.readlines()
            self.assertTrue(any("### [quick]" in line for line in lines))
            with open(readme, "w") as f:
                f.writelines(line for line in lines if not line.startswith("Command:"))
            p = subprocess.run([sys.executable, script, "--check"], capture_output=True, text=True)
            self.assertEqual(p.returncode, 1, p.stderr)
            self.assertIn("is stale", p.stderr)


if __name__ == "__main__":
    unittest.main()
