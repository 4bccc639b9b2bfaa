"""reports/denoise_accuracy/report.md is what reports/denoise_accuracy/plot.py --report-only writes
from the CSV files beside it (so no figure in it can go stale), and a damaged CSV is one clear line
naming the file and line (exit status 2, never a traceback). Runs plot.py on a scratch copy of the
folder; needs only the Python standard library (--report-only does not import matplotlib)."""
import difflib
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
FOLDER = os.path.join(ROOT, "reports", "denoise_accuracy")
PLOT = os.path.join(FOLDER, "plot.py")
CSVS = ("accuracy.csv", "svgf_variants_room.csv", "light_history_frame8.csv", "light_history_frame40.csv")
REFRESH = "/usr/bin/python3 reports/denoise_accuracy/plot.py --report-only"


def scratch_copy(tmp):
    dst = os.path.join(tmp, "denoise_accuracy")
    os.makedirs(dst)
    for name in CSVS:
        shutil.copy(os.path.join(FOLDER, name), dst)
    return dst


def run_plot(folder):
    return subprocess.run([sys.executable, PLOT, "--report-only", os.path.join(folder, "accuracy.csv")],
                          capture_output=True, text=True)


class DenoiseAccuracyReport(unittest.TestCase):
    def test_report_md_regenerates_identically(self):
        with tempfile.TemporaryDirectory() as tmp:
            dst = scratch_copy(tmp)
            p = run_plot(dst)
            self.assertEqual(p.returncode, 0, p.stderr)
            self.assertFalse(os.path.exists(os.path.join(dst, "accuracy.png")), "--report-only drew the figure")
            with open(os.path.join(FOLDER, "report.md"), encoding="utf-8", newline="") as f:
                have = f.read()
            with open(os.path.join(dst, "report.md"), encoding="utf-8", newline="") as f:
                written = f.read()
            if have != written:
                diff = "".join(list(difflib.unified_diff(have.splitlines(True), written.splitlines(True),
                                                         "reports/denoise_accuracy/report.md", "written"))[:40])
                self.fail(f"reports/denoise_accuracy/report.md differs from what its CSVs give "
                          f"(refresh: {REFRESH}):\n{diff}")

    def test_row_missing_a_field_is_one_clear_line(self):
        with tempfile.TemporaryDirectory() as tmp:
            dst = scratch_copy(tmp)
            path = os.path.join(dst, "accuracy.csv")
            with open(path, encoding="utf-8") as f:
                lines = f.read().splitlines(True)
            lines[4] = lines[4].rstrip("\n").rsplit(",", 1)[0] + "\n"  # line 5 loses its last field
            with open(path, "w", encoding="utf-8") as f:
                f.writelines(lines)
            p = run_plot(dst)
            self.assertEqual(p.returncode, 2, p.stderr)
            self.assertNotIn("Traceback", p.stderr)
            self.assertEqual(len(p.stderr.strip().splitlines()), 1, p.stderr)
            self.assertIn(f"{path}:5:", p.stderr)
            self.assertIn("a field is missing", p.stderr)
            self.assertFalse(os.path.exists(os.path.join(dst, "report.md")), "a report was written from a bad CSV")

    def test_value_that_is_not_a_number_is_one_clear_line(self):
        with tempfile.TemporaryDirectory() as tmp:
            dst = scratch_copy(tmp)
            path = os.path.join(dst, "light_history_frame40.csv")
            with open(path, encoding="utf-8") as f:
                lines = f.read().splitlines(True)
            fields = lines[2].split(",")
            fields[7] = "n/a"  # ssim
            lines[2] = ",".join(fields)
            with open(path, "w", encoding="utf-8") as f:
                f.writelines(lines)
            p = run_plot(dst)
            self.assertEqual(p.returncode, 2, p.stderr)
            self.assertNotIn("Traceback", p.stderr)
            self.assertEqual(p.stderr.strip(), f"plot.py: {path}:3: field ssim = 'n/a' is not a number")


if __name__ == "__main__":
    unittest.main()
