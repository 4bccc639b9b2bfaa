"""The results reader (experiments/dhrbench_results): reports/quick loads into tables, and damaged
copies of it are one clear error naming the file and the field (never a traceback)."""
import gzip
import json
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
EXPERIMENTS = os.path.join(ROOT, "experiments")
sys.path.insert(0, EXPERIMENTS)
import dhrbench_results as dr  # noqa: E402

QUICK = os.path.join(ROOT, "reports", "quick")
try:
    import pandas  # noqa: F401
except ImportError:
    pandas = None


class Quick(unittest.TestCase):
    def test_loads_and_checks(self):
        res = dr.load(QUICK)
        self.assertEqual(len(res.results["runs"]), 11)
        self.assertEqual(len(res.frames), 660)
        self.assertEqual(res.headline["name"], "ssim")
        self.assertTrue(res.frames_path.endswith("frames.csv"))

    @unittest.skipIf(pandas is None, "pandas is not installed (python3-pandas, scripts/setup.sh)")
    def test_tables(self):
        res = dr.load(QUICK)
        runs = dr.runs_frame(res)
        self.assertEqual(list(runs["id"]), [f"r{i:03d}" for i in range(11)])
        self.assertEqual(runs.loc[0, "settings.network"], "5g")
        self.assertAlmostEqual(runs.loc[0, "bandwidth_mbps"], res.results["runs"][0]["metrics"]["bandwidth_mbps"])
        self.assertIn("passes.visibility.bytes_per_frame", runs.columns)
        self.assertIn("stages_wall.encode.median_ms", runs.columns)
        units = runs.attrs["units"]
        self.assertEqual(units["bandwidth_mbps"], "Mb/s")
        self.assertEqual(units["psnr_local_mean_db"], "db")
        self.assertEqual(units["ssim_local_mean"], "")
        self.assertEqual(units["stages_wall.encode.median_ms"], "ms")
        frames = dr.frames_frame(res)
        self.assertEqual(len(frames), 660)
        self.assertEqual(str(frames["frame"].dtype), "int64")
        self.assertEqual(frames.attrs["units"]["psnr_local_db"], "db")
        # The run means of results.json are the means of the frames (to the CSV's 6 digits).
        ssim = frames.groupby("run")["ssim_local"].mean()
        for r in res.results["runs"]:
            self.assertAlmostEqual(ssim[r["id"]], r["metrics"]["ssim_local_mean"], places=5)

    @unittest.skipIf(pandas is None, "pandas is not installed")
    def test_summary_command(self):
        p = subprocess.run([sys.executable, "-m", "dhrbench_results", QUICK], cwd=EXPERIMENTS,
                           capture_output=True, text=True)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn("11 runs (11 with metrics), 660 frames", p.stdout)
        self.assertIn("remote h264 crf 23, 5G", p.stdout)


class Damaged(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="dhr_reader_")
        for name in ("results.json", "frames.csv"):
            shutil.copy(os.path.join(QUICK, name), self.dir)
        self.frames = os.path.join(self.dir, "frames.csv")
        self.results = os.path.join(self.dir, "results.json")

    def tearDown(self):
        shutil.rmtree(self.dir)

    def expect(self, *parts):
        with self.assertRaises(dr.BadResults) as cm:
            dr.load(self.dir)
        for p in parts:
            self.assertIn(p, str(cm.exception))
        # The command: exit 2, one line, the same message, no traceback.
        p = subprocess.run([sys.executable, "-m", "dhrbench_results", self.dir], cwd=EXPERIMENTS,
                           capture_output=True, text=True)
        self.assertEqual(p.returncode, 2, p.stderr)
        self.assertNotIn("Traceback", p.stderr)
        self.assertEqual(p.stderr.count("\n"), 1, p.stderr)
        self.assertIn(str(cm.exception), p.stderr)
        return str(cm.exception)

    def edit_results(self, f):
        with open(self.results) as fh:
            r = json.load(fh)
        f(r)
        with open(self.results, "w") as fh:
            json.dump(r, fh)

    def test_frames_cut_inside_a_row(self):
        with open(self.frames) as f:
            text = f.read()
        with open(self.frames, "w") as f:
            f.write(text[:len(text) // 2 + 7])
        self.expect(self.frames + ": the file ends inside its last row (cut short)")

    def test_gzip_frames_cut_short(self):
        with open(self.frames, "rb") as f:
            data = gzip.compress(f.read())
        os.remove(self.frames)
        with open(self.frames + ".gz", "wb") as f:
            f.write(data[:len(data) // 2])
        self.expect(self.frames + ".gz: not a CSV file as 'dhrbench run' writes it")

    def test_a_row_of_an_unknown_run(self):
        with open(self.frames) as f:
            lines = f.read().splitlines(keepends=True)
        lines.append(lines[-1].replace("r010", "r999", 1))
        with open(self.frames, "w") as f:
            f.writelines(lines)
        self.expect(self.frames, 'rows of run "r999", which results.json does not hold')

    def test_a_run_with_no_metrics(self):
        self.edit_results(lambda r: r["runs"][1].pop("metrics"))
        self.expect(self.results, 'runs[1] (r001) has neither "metrics" nor "error"')

    def test_a_run_missing_a_metric(self):
        self.edit_results(lambda r: r["runs"][2]["metrics"].pop("bandwidth_mbps"))
        self.expect(self.results, "runs[2].metrics.bandwidth_mbps is missing")

    def test_a_row_too_few(self):
        with open(self.frames) as f:
            lines = f.read().splitlines(keepends=True)
        with open(self.frames, "w") as f:
            f.writelines(lines[:-1])
        self.expect(self.frames, "run r010 has 59 row(s), but results.json says it displayed 60 frame(s)")

    def test_a_bad_number(self):
        with open(self.frames) as f:
            lines = f.read().splitlines(keepends=True)
        head = lines[0].rstrip("\n").split(",")
        cells = lines[1].rstrip("\n").split(",")
        cells[head.index("frame") + 2] = "x"  # the label holds a comma: two fields on
        lines[1] = ",".join(cells) + "\n"
        with open(self.frames, "w") as f:
            f.writelines(lines)
        self.expect(self.frames + ": line 2: frame must be an integer")

    def test_no_frames(self):
        os.remove(self.frames)
        self.expect(self.frames + ": missing")


if __name__ == "__main__":
    unittest.main()
