"""Tests of scripts/sph_disorder.py on synthetic 2D snapshots whose figures are known by hand.

Run from the repository root: .venv/bin/python -m unittest discover -s tests/python -v

First file: a 4 x 4 lattice of spacing 1 in the box [0, 4)^2 (first site at 1/2), periodic in
x, walls in y, with two particles moved:
 - (0.5, 0.5) -> (0.2, 0.5): through the periodic x face it is 0.7 from (3.5, 0.5), so both
   have nearest distance 0.7 (without the wrap: 1.044 and 1.0);
 - (1.5, 3.5) -> (1.5, 3.9): y is not periodic, so its nearest is (0.5, 3.5) or (2.5, 3.5) at
   sqrt(1.16) (through a y wrap it would be 0.6 from (1.5, 0.5));
 - the other 13 have nearest distance 1. A wall particle (kind 1) at (2.5, 1.0), 0.5 from two
   fluid particles, must be left out.
Densities: 14 at 1000, one at 990, one at 1010: mean 1000, std sqrt(200 / 16).
Second file: the 2 x 2 sublattice of the perfect lattice (spacing 2, nearest distance 2).
"""
import math
import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import h5py

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCRIPT = os.path.join(ROOT, "scripts", "sph_disorder.py")
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import sph_disorder  # noqa: E402

INPUT = """&domain
    dimension = 2
    box_lo = 0.0, 0.0, 0.0
    box_hi = 4.0, 4.0, 0.0
    dx = 1.0
    boundary = 'periodic', 'periodic', 'wall', 'wall', 'periodic', 'periodic'
/
"""


def write(path, pos, kind, rho, text=INPUT, volume=None, h=1.0, level=None):
    """A snapshot of these particles; masses rho * volume (all 1 without volume)."""
    n = len(pos)
    with h5py.File(path, "w") as f:
        f.attrs["time"] = 0.0
        f.attrs["step"] = np.int64(0)
        f.attrs["dimension"] = np.int32(2)
        f.attrs["input"] = text
        f.attrs["format"] = "sphremesh-snapshot"
        f.attrs["format_version"] = np.int32(1)
        g = f.create_group("particles")
        g["position"] = np.asarray(pos, dtype=float)
        g["velocity"] = np.zeros((n, 3))
        g["density"] = np.asarray(rho, dtype=float)
        for name in ("pressure", "energy"):
            g[name] = np.ones(n)
        g["mass"] = np.ones(n) if volume is None else np.asarray(rho, dtype=float) * volume
        g["smoothing_length"] = np.full(n, h)
        g["id"] = np.arange(1, n + 1, dtype=np.int64)
        g["kind"] = np.asarray(kind, dtype=np.int32)
        g["level"] = np.zeros(n, dtype=np.int32) if level is None else \
            np.asarray(level, dtype=np.int32)
        g["rank"] = np.zeros(n, dtype=np.int32)
        f.attrs["write_complete"] = np.int32(1)


class DisorderTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory()
        pos = [[i + 0.5, j + 0.5, 0.0] for j in range(4) for i in range(4)]
        pos[0] = [0.2, 0.5, 0.0]                 # (0.5, 0.5) moved
        pos[13] = [1.5, 3.9, 0.0]                # (1.5, 3.5) moved
        rho = [1000.0] * 16
        rho[5], rho[10] = 990.0, 1010.0
        pos.append([2.5, 1.0, 0.0])              # a wall particle
        rho.append(500.0)
        kind = [0] * 16 + [1]
        cls.first = os.path.join(cls.tmp.name, "first.h5")
        write(cls.first, pos, kind, rho)
        coarse = [[i + 0.5, j + 0.5, 0.0] for j in (0, 2) for i in (0, 2)]
        cls.second = os.path.join(cls.tmp.name, "second.h5")
        write(cls.second, coarse, [0] * 4, [1000.0] * 4)
        nn = np.array([0.7, 0.7, math.sqrt(1.16)] + [1.0] * 13)
        cls.mean = nn.mean()
        cls.cov = math.sqrt(np.mean((nn - cls.mean) ** 2)) / cls.mean

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def test_one_file_figures(self):
        s = sph_disorder.disorder(self.first)
        self.assertEqual(s["count"], 16)                         # the wall particle left out
        self.assertEqual(s["periodic"], [True, False])
        self.assertAlmostEqual(s["mean_nn"], self.mean, places=12)
        self.assertAlmostEqual(s["cov_nn"], self.cov, places=12)
        self.assertAlmostEqual(s["min_pair"], 0.7, places=12)    # across the periodic face
        # the distances themselves (validate's histograms): 0.7 twice, sqrt(1.16) once, 1
        np.testing.assert_allclose(np.sort(s["nearest"]),
                                   [0.7, 0.7] + [1.0] * 13 + [math.sqrt(1.16)], rtol=1e-12)
        self.assertEqual((s["rho_min"], s["rho_max"]), (990.0, 1010.0))
        self.assertAlmostEqual(s["rho_spread"], math.sqrt(200.0 / 16.0) / 1000.0, places=14)

    def test_two_files_ratios_on_the_command_line(self):
        run = subprocess.run([sys.executable, SCRIPT, self.first, self.second],
                             capture_output=True, text=True)
        self.assertEqual(run.returncode, 0, run.stderr)
        lines = {line.split("  ")[1].strip(): line.split()[-1]
                 for line in run.stdout.splitlines() if "ratio" in line}
        self.assertAlmostEqual(float(lines["count ratio"]), 0.25, places=5)
        self.assertAlmostEqual(float(lines["mean nearest ratio"]), 2.0 / self.mean, places=5)
        self.assertAlmostEqual(float(lines["CoV ratio"]), 0.0, places=5)
        self.assertIn("periodic axes: x", run.stdout)

    def test_missing_file_is_a_message(self):
        run = subprocess.run([sys.executable, SCRIPT, os.path.join(self.tmp.name, "no.h5")],
                             capture_output=True, text=True)
        self.assertEqual(run.returncode, 1)
        self.assertIn("sph_disorder:", run.stderr)
        self.assertNotIn("Traceback", run.stderr)


class VolumeSumTest(unittest.TestCase):
    """The kernel sums of volumes on a periodic 10 x 10 lattice of spacing 1 (volumes 1,
    h = 1.3): every sum is the lattice sum S of the cubic spline; with the site (4.5, 4.5)
    taken out, its four nearest neighbours lack W(1, 1.3) and its four diagonal ones
    W(sqrt 2, 1.3). A wall particle (kind 1) counts; a mirror (kind 3) does not."""

    TEXT = INPUT.replace("'wall', 'wall'", "'periodic', 'periodic'").replace(
        "4.0, 4.0", "10.0, 10.0")

    def sums(self, pos, kind):
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "lattice.h5")
            write(path, pos, kind, [1000.0] * len(pos), text=self.TEXT, volume=1.0, h=1.3)
            snap = sph_disorder.load(path, check_format=False)
            geo = sph_disorder.geometry(snap)
            return sph_disorder.volume_sums(snap, geo, [True, True]), \
                sph_disorder.disorder(path)

    def test_even_lattice_and_a_hole(self):
        w = lambda r: sph_disorder.cubic_spline(np.asarray(r), 1.3, 2)  # noqa: E731
        lattice = [[i + 0.5, j + 0.5, 0.0] for j in range(10) for i in range(10)]
        # the lattice sum: offsets up to 2 h = 2.6 (|i|, |j| <= 2)
        total = float(sum(w(math.hypot(i, j)) for i in range(-2, 3) for j in range(-2, 3)))
        sums, stats = self.sums(lattice, [0] * 100)
        self.assertTrue(np.allclose(sums, total, rtol=1e-12, atol=0.0))
        self.assertLess(stats["volume_sum_spread"], 1e-12)
        self.assertAlmostEqual(stats["volume_sum_mean"], total, places=12)
        # the hole at (4.5, 4.5) = site 44, now a mirror (left out), and a wall particle on
        # a far site instead of a fluid one (counted: its sums stay the lattice's)
        kind = [0] * 100
        kind[44] = 3
        kind[0] = 1
        sums, stats = self.sums(lattice, kind)
        fluid = [k for k in range(100) if kind[k] == 0]
        by_site = dict(zip(fluid, sums))
        self.assertAlmostEqual(by_site[45], total - float(w(1.0)), places=12)
        self.assertAlmostEqual(by_site[55], total - float(w(math.sqrt(2.0))), places=12)
        self.assertAlmostEqual(by_site[1], total, places=12)
        self.assertGreater(stats["volume_sum_spread"], 0.01)


class LevelsTest(unittest.TestCase):
    """A multi-resolution snapshot: two even lattices (spacings 1 and 1/2, the fine one in
    y < 2). Mixed, their nearest distances read as a disorder (CoV 0.3); measured one level
    at a time, each is even. Without virtual particles its kernel sums are not given."""

    def test_one_level_at_a_time(self):
        with tempfile.TemporaryDirectory() as tmp:
            coarse = [[i + 0.5, j + 0.5, 0.0] for j in range(2, 4) for i in range(4)]
            fine = [[0.5 * i + 0.25, 0.5 * j + 0.25, 0.0] for j in range(4) for i in range(8)]
            path = os.path.join(tmp, "levels.h5")
            write(path, coarse + fine, [0] * 40, [1000.0] * 40, level=[0] * 8 + [1] * 32)
            with self.assertRaises(sph_disorder.SnapshotError):
                sph_disorder.disorder(path)
            for level, count, spacing in ((0, 8, 1.0), (1, 32, 0.5)):
                s = sph_disorder.disorder(path, level)
                self.assertEqual(s["count"], count)
                self.assertAlmostEqual(s["mean_nn"], spacing)
                self.assertAlmostEqual(s["cov_nn"], 0.0)
                self.assertTrue(math.isnan(s["volume_sum_mean"]))


if __name__ == "__main__":
    unittest.main()
