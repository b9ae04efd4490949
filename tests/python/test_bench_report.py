"""Tests of bench/bench_report.py (the benchmark suite's table) on synthetic run logs: the
figures it derives (ns per particle-step x ranks, pair interactions per second, medians and
ranges, 2-rank efficiency) and the CSV it writes.

    .venv/bin/python -m unittest discover -s tests/python -v
"""
import contextlib
import csv
import io
import os
import sys
import tempfile
import unittest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import bench_report  # noqa: E402


def log_text(particles, steps, wall, evaluations, neighbours=20.0, bytes_per=800.0):
    """The lines of a run's log that the report reads, as sphremesh writes them."""
    split = [0.1, 0.6, 0.05, 0.2, 0.05, 0.0]
    parts = ', '.join('%s %.3f s (%.1f %%)' % (name, f * wall, 100 * f)
                      for name, f in zip(bench_report.PARTS, split))
    return '\n'.join([
        'particles: %d real (fluid %d), load imbalance  1.000' % (particles, particles - 10),
        'finished: %d steps to t =  2.64063E-02 s in %11.3f s wall' % (steps, wall),
        'peak memory:       87.0 MB over all ranks (largest rank       87.0 MB), '
        '%8.1f bytes per particle' % bytes_per,
        'time split: %s; %.3f s timed, %d rate evaluations' % (parts, wall, evaluations),
        'neighbours: %.2f per particle within the kernel support' % neighbours,
    ]) + '\n'


class TestBenchReport(unittest.TestCase):

    def setUp(self):
        self.out = tempfile.mkdtemp()
        os.makedirs(os.path.join(self.out, 'logs'))
        with open(os.path.join(self.out, 'machine.txt'), 'w') as f:
            f.write('cpu: test\n')

    def write(self, name, text):
        with open(os.path.join(self.out, 'logs', name), 'w') as f:
            f.write(text)

    def report(self):
        with contextlib.redirect_stdout(io.StringIO()) as printed:
            sys.argv = ['bench_report.py', self.out]
            bench_report.main()
        with open(os.path.join(self.out, 'bench.csv')) as f:
            rows = list(csv.DictReader(f))
        return printed.getvalue(), rows

    def test_figures_medians_and_efficiency(self):
        # 1 rank: 1000 particles, 100 steps, walls 2, 3, 10 s: median 3 s = 30,000 ns
        for rep, wall in enumerate([2.0, 3.0, 10.0], start=1):
            self.write('case_verlet_np1_r%d.log' % rep, log_text(1000, 100, wall, 101))
        # 2 ranks: 2 s = 40,000 ns x ranks: efficiency 75 %
        for rep, wall in enumerate([2.0, 2.0], start=1):
            self.write('case_verlet_np2_r%d.log' % rep, log_text(1000, 100, wall, 101))
        printed, rows = self.report()
        self.assertEqual(len(rows), 2)
        one, two = rows
        self.assertEqual((one['ranks'], two['ranks']), ('1', '2'))
        self.assertAlmostEqual(float(one['wall']), 3.0)
        self.assertAlmostEqual(float(one['wall_min']), 2.0)
        self.assertAlmostEqual(float(one['wall_max']), 10.0)
        self.assertAlmostEqual(float(one['ns']), 3.0e9 / (1000 * 100))
        self.assertAlmostEqual(float(two['ns']), 2.0 * 2.0e9 / (1000 * 100))
        self.assertEqual(two['efficiency'], '75')
        # pairs within the support, each once, per rate evaluation: 1000 x 20 / 2 x 101 / 3 s
        self.assertAlmostEqual(float(one['pairs_per_s']), 1000 * 10.0 * 101 / 3.0)
        self.assertAlmostEqual(float(one['rates']), 60.0, places=6)
        self.assertAlmostEqual(float(one['bytes']), 800.0)
        self.assertIn('cpu: test', printed)
        self.assertTrue(os.path.exists(os.path.join(self.out, 'bench.png')))

    def test_integrators_and_cases_are_kept_apart(self):
        self.write('a_predictor_corrector_np1_r1.log', log_text(1000, 10, 4.0, 20))
        self.write('a_verlet_np1_r1.log', log_text(1000, 10, 2.0, 11))
        self.write('b_verlet_np1_r1.log', log_text(5000, 10, 2.0, 11))
        _, rows = self.report()
        keys = sorted((r['case'], r['integrator']) for r in rows)
        self.assertEqual(keys, [('a', 'predictor_corrector'), ('a', 'verlet'), ('b', 'verlet')])
        walls = dict(((r['case'], r['integrator']), float(r['wall'])) for r in rows)
        self.assertEqual(walls[('a', 'predictor_corrector')], 4.0)
        self.assertEqual(walls[('a', 'verlet')], 2.0)


MULTIRES_TABLE = """# sphremesh multi-resolution benchmark (thesis Fig. 5-2), 1 rank(s); wall s per simulated s
#                                               ---- predictor-corrector, one time step ----   ---- Verlet, coarse level sub-cycled (4) ----
# dx fine   particles: uniform  multi (real + virtual)      uniform       multi    (zones) multi/uniform      uniform       multi    (zones) multi/uniform
  L/160              106240        47356 + 2080         4.6335E+03  2.5991E+03   3.35E+02       0.561         2.8294E+03  1.4402E+03   3.24E+02       0.509
  L/320              417280       184156 + 4160         8.0376E+04  4.4107E+04   3.42E+03       0.549         4.2030E+04  1.8282E+04   2.56E+03       0.435
"""


class TestMultiresStudy(unittest.TestCase):

    def test_rows_and_plot(self):
        out = tempfile.mkdtemp()
        path = os.path.join(out, 'multires_np1.txt')
        with open(path, 'w') as f:
            f.write(MULTIRES_TABLE)
        rows = bench_report.parse_multires(path)
        self.assertEqual([r['fine'] for r in rows], ['L/160', 'L/320'])
        self.assertEqual(rows[1]['uniform_particles'], 417280)
        self.assertEqual((rows[1]['real'], rows[1]['virtual']), (184156, 4160))
        self.assertAlmostEqual(rows[1]['pc']['ratio'], 0.549)
        self.assertAlmostEqual(rows[1]['verlet']['multi'], 1.8282e4)
        self.assertAlmostEqual(rows[0]['verlet']['zones'], 3.24e2)
        self.assertEqual(bench_report.parse_multires(os.path.join(out, 'missing.txt')), [])
        png = os.path.join(out, 'multires.png')
        bench_report.plot_multires({1: rows, 2: []}, png)
        self.assertTrue(os.path.getsize(png) > 0)


if __name__ == '__main__':
    unittest.main()
