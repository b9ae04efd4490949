"""Tests of the Python post-processing tools (scripts/sph_*.py) on synthetic snapshots.

Run from the repository root (no pytest needed):

    .venv/bin/python -m unittest discover -s tests/python -v

Each test class writes a small snapshot series with h5py into a temporary directory,
following the schema of doc/output.md exactly (root attributes, the resolved input text,
/particles datasets), with fluid velocities set to the analytic solution, plus a matching
XDMF file as the code writes it. The commands are run as subprocesses (exit status, messages,
no traceback) and their functions are called directly.
"""
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import h5py

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCRIPTS = os.path.join(ROOT, "scripts")
sys.path.insert(0, SCRIPTS)

import sph_analytic  # noqa: E402
import sph_check_xdmf  # noqa: E402
import sph_error_table  # noqa: E402
import sph_snapshot  # noqa: E402

TIMES = (0.0, 0.0225, 0.225, 1.0)
STEPS = (0, 171, 1705, 7575)
FIELDS_1D = ("density", "pressure", "mass", "smoothing_length", "energy", "id", "kind",
             "level", "rank")


def input_text(case, dim, box_hi, dx, nu, force, wall_speed):
    """A resolved namelist like the one the code stores in every file."""
    faces = np.zeros((6, 3))
    faces[3, 0] = wall_speed                      # yhi face moves along x (Couette)
    wall = ", ".join(f"{v:.17g}" for v in faces.reshape(-1))   # Fortran order (1:3, face)
    hi = ", ".join(f"{v:.17g}" for v in box_hi)
    return f"""&run
    case_name = 'synthetic'
    t_end = 1.0
    analytic = '{case}'
/
&output
    output_dir = 'output/synthetic'
/
&domain
    dimension = {dim}
    box_lo = 0.0, 0.0, 0.0
    box_hi = {hi}
    dx = {dx:.17g}
    boundary = 'periodic', 'periodic', 'wall', 'wall', 'periodic', 'periodic'
    wall_velocity = {wall}
/
&fluid
    rho0 = 1000.0
    nu = {nu:.17g}
    body_force = {force:.17g}, 0.0, 0.0
/
"""


def lattice(dim, box_hi, dx, wall_rows=3):
    """Fluid particles on the lattice (first at dx/2) and wall_rows rows of wall particles
    below y = 0 and above y = L (periodic in x and z)."""
    nx = int(round(box_hi[0] / dx))
    ny = int(round(box_hi[1] / dx))
    nz = int(round(box_hi[2] / dx)) if dim == 3 else 1
    xs = (np.arange(nx) + 0.5) * dx
    zs = (np.arange(nz) + 0.5) * dx if dim == 3 else np.zeros(1)
    rows = np.arange(-wall_rows, ny + wall_rows)
    ys = (rows + 0.5) * dx
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    R = np.broadcast_to(rows[None, :, None], X.shape)
    pos = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    r = R.ravel()
    kind = np.where((r < 0) | (r >= ny), 1, 0).astype(np.int32)
    return pos, kind


def write_snapshot(path, *, time, step, dim, text, pos, kind, vel, nranks=2,
                   complete=True):
    n = len(pos)
    rank = (np.arange(n) * nranks // max(n, 1)).astype(np.int32)
    with h5py.File(path, "w") as f:
        f.attrs["time"] = np.float64(time)
        f.attrs["step"] = np.int64(step)
        f.attrs["dimension"] = np.int32(dim)
        # one string as fixed-length bytes, as some HDF5 writers give: load() must decode it
        f.attrs["code_version"] = np.bytes_(b"sphremesh 0.1.0 (synthetic test)")
        f.attrs["input"] = text
        f.attrs["nranks"] = np.int32(nranks)
        f.attrs["date"] = "2026-05-09T07:29:33Z"
        f.attrs["format"] = "sphremesh-snapshot"
        f.attrs["format_version"] = np.int32(1)
        g = f.create_group("particles")
        g["position"] = pos.astype(np.float64)
        g["velocity"] = vel.astype(np.float64)
        g["density"] = 1000.0 + 0.01 * np.sin(pos[:, 1] * 1e4)
        g["pressure"] = 1e-3 * np.cos(pos[:, 1] * 1e4)
        g["mass"] = np.full(n, 1000.0 * 1e-8)
        g["smoothing_length"] = np.full(n, 1.3e-4)
        g["energy"] = np.linspace(0.0, 1e-9, n)
        g["id"] = np.arange(1, n + 1, dtype=np.int64)
        g["kind"] = kind.astype(np.int32)
        g["level"] = np.zeros(n, dtype=np.int32)
        g["rank"] = rank
        if complete:
            f.attrs["write_complete"] = np.int32(1)      # written last


def write_xdmf(path, entries):
    """entries: (file name, time, step, N) per snapshot; the code's layout (Xdmf 3)."""
    types = {"velocity": ("Vector", "Float", 8), "density": ("Scalar", "Float", 8),
             "pressure": ("Scalar", "Float", 8), "mass": ("Scalar", "Float", 8),
             "smoothing_length": ("Scalar", "Float", 8), "energy": ("Scalar", "Float", 8),
             "id": ("Scalar", "Int", 8), "kind": ("Scalar", "Int", 4),
             "level": ("Scalar", "Int", 4), "rank": ("Scalar", "Int", 4)}
    lines = ['<?xml version="1.0" ?>', '<Xdmf Version="3.0">', ' <Domain>',
             '  <Grid Name="particles" GridType="Collection" CollectionType="Temporal">']
    for name, time, step, n in entries:
        lines += [f'   <Grid Name="step_{step}" GridType="Uniform">',
                  f'    <Time Value="{time:24.16E}"/>',
                  f'    <Topology TopologyType="Polyvertex" NumberOfElements="{n}"/>',
                  '    <Geometry GeometryType="XYZ">',
                  f'     <DataItem Dimensions="{n} 3" NumberType="Float" Precision="8" '
                  f'Format="HDF">{name}:/particles/position</DataItem>',
                  '    </Geometry>']
        for field, (atype, ntype, prec) in types.items():
            dims = f"{n} 3" if atype == "Vector" else f"{n}"
            lines += [f'    <Attribute Name="{field}" AttributeType="{atype}" Center="Node">',
                      f'     <DataItem Dimensions="{dims}" NumberType="{ntype}" Precision="{prec}" '
                      f'Format="HDF">{name}:/particles/{field}</DataItem>',
                      '    </Attribute>']
        lines.append('   </Grid>')
    lines += ['  </Grid>', ' </Domain>', '</Xdmf>']
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def make_series(folder, case="poiseuille", dim=2, name="synthetic"):
    """A snapshot series with exact analytic velocities and its XDMF file; returns paths."""
    width, dx, nu, force, wall_speed = 1.0e-3, 1.0e-4, 1.0e-6, 2.0e-4, 1.0e-5
    box_hi = (0.5e-3, width, 0.4e-3 if dim == 3 else 0.0)
    # (a Couette input with a body force is Couette-Poiseuille flow, whose reference adds the
    # force's series: the series' Couette flow has none)
    text = input_text(case, dim, box_hi, dx, nu, force if case == "poiseuille" else 0.0,
                      wall_speed if case == "couette" else 0.0)
    pos, kind = lattice(dim, box_hi, dx)
    fluid = kind == 0
    paths, entries = [], []
    for time, step in zip(TIMES, STEPS):
        vel = np.zeros_like(pos)
        if case == "poiseuille":
            vel[fluid, 0] = sph_analytic.poiseuille(pos[fluid, 1], time, force, width, nu)
        else:
            vel[fluid, 0] = sph_analytic.couette(pos[fluid, 1], time, wall_speed, width, nu)
            vel[kind == 1, 0] = np.where(pos[kind == 1, 1] > width, wall_speed, 0.0)
        file_name = f"{name}_{step:06d}.h5"
        path = os.path.join(folder, file_name)
        write_snapshot(path, time=time, step=step, dim=dim, text=text, pos=pos, kind=kind,
                       vel=vel)
        paths.append(path)
        entries.append((file_name, time, step, len(pos)))
    xdmf = os.path.join(folder, f"{name}.xdmf")
    write_xdmf(xdmf, entries)
    return paths, xdmf


def run(script, *args):
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run([sys.executable, os.path.join(SCRIPTS, script), *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=300)


def call_main(module, *args):
    """A script's main(argv) called in this process, as run() gives it (returncode, stdout,
    stderr) but without starting Python, numpy and h5py anew (0.3 s a call); an exception
    fails the test as a traceback would."""
    import contextlib
    import importlib
    import io
    os.environ.setdefault("MPLBACKEND", "Agg")
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            status = importlib.import_module(module).main(list(map(str, args)))
        except SystemExit as stop:
            status = stop.code if isinstance(stop.code, int) else 1
            if not isinstance(stop.code, int) and stop.code is not None:
                print(stop.code, file=sys.stderr)
    return subprocess.CompletedProcess([module, *args], status, out.getvalue(), err.getvalue())


def is_png(path, min_bytes=5000):
    if not os.path.isfile(path) or os.path.getsize(path) < min_bytes:
        return False
    with open(path, "rb") as f:
        return f.read(8) == b"\x89PNG\r\n\x1a\n"


class ScriptTestCase(unittest.TestCase):

    def assertCleanFailure(self, result, *fragments):
        """Exit 1, a message naming the problem, no traceback."""
        self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
        self.assertNotIn("Traceback", result.stderr)
        for fragment in fragments:
            self.assertIn(fragment, result.stderr)


class PostProcessingTestCase(ScriptTestCase):
    case, dim = "poiseuille", 2

    @classmethod
    def setUpClass(cls):
        cls.folder = tempfile.mkdtemp(prefix=f"sph_pp_{cls.case}{cls.dim}d_")
        cls.paths, cls.xdmf = make_series(cls.folder, cls.case, cls.dim)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.folder, ignore_errors=True)


class TestSnapshot(PostProcessingTestCase):

    def test_load_round_trip(self):
        snap = sph_snapshot.load(self.paths[2])
        with h5py.File(self.paths[2], "r") as f:
            for name in ("position", "velocity") + FIELDS_1D:
                np.testing.assert_array_equal(snap[name], f["particles"][name][()], err_msg=name)
                self.assertEqual(snap[name].dtype, f["particles"][name].dtype)
        self.assertEqual(snap["position"].shape, (len(snap["id"]), 3))
        attrs = snap["attrs"]
        self.assertEqual(attrs["time"], TIMES[2])
        self.assertEqual(attrs["step"], STEPS[2])
        self.assertEqual(attrs["dimension"], self.dim)
        self.assertEqual(attrs["write_complete"], 1)
        for key in ("code_version", "input", "date", "format"):
            self.assertIsInstance(attrs[key], str, key)
        self.assertEqual(attrs["code_version"], "sphremesh 0.1.0 (synthetic test)")
        self.assertEqual(snap["time"], TIMES[2])
        self.assertIn(f"analytic = '{self.case}'", snap["input"])
        geo = sph_snapshot.geometry(snap)
        self.assertEqual(geo["dimension"], self.dim)
        self.assertAlmostEqual(geo["dx"], 1e-4)

    def test_list_snapshots_sorted_by_step(self):
        # decoys: a checkpoint, a failure snapshot, an unfinished .tmp, another case, a
        # 7-digit step
        extra = tempfile.mkdtemp(dir=self.folder)
        for name in ("a_000010.h5", "a_000002.h5", "a_1000000.h5", "a_checkpoint_000010.h5",
                     "a_failure_000012.h5", "a_000011.h5.tmp", "b_000005.h5", "a.xdmf"):
            open(os.path.join(extra, name), "w").close()
        names = [os.path.basename(p) for p in sph_snapshot.list_snapshots(extra, case="a")]
        self.assertEqual(names, ["a_000002.h5", "a_000010.h5", "a_1000000.h5"])
        self.assertEqual(len(sph_snapshot.list_snapshots(extra)), 4)
        found = sph_snapshot.list_snapshots(self.folder)
        self.assertEqual(found, self.paths)
        with self.assertRaises(ValueError):
            sph_snapshot.list_snapshots(os.path.join(self.folder, "missing"))

    def test_incomplete_file_refused(self):
        path = os.path.join(self.folder, "incomplete_000001.h5")
        pos, kind = lattice(2, (1e-3, 1e-3, 0), 2.5e-4)
        write_snapshot(path, time=0.1, step=1, dim=2, text="", pos=pos, kind=kind,
                       vel=np.zeros_like(pos), complete=False)
        try:
            with self.assertRaisesRegex(ValueError, "write_complete"):
                sph_snapshot.load(path)
            self.assertCleanFailure(run("sph_snapshot.py", path), "incomplete")
        finally:
            os.remove(path)

    def test_summary_command(self):
        result = run("sph_snapshot.py", self.paths[-1])
        self.assertEqual(result.returncode, 0, result.stderr)
        n_fluid = sum(sph_snapshot.load(self.paths[-1])["kind"] == 0)
        self.assertIn(f"fluid {n_fluid}", result.stdout)
        self.assertIn("time 1 s, step 7575", result.stdout)
        for field in ("velocity_x", "density", "rank"):
            self.assertIn(field, result.stdout)
        self.assertCleanFailure(run("sph_snapshot.py", os.path.join(self.folder, "nope.h5")),
                                "nope.h5")
        self.assertCleanFailure(run("sph_snapshot.py", self.xdmf), "not a readable HDF5 file")
        # a failure snapshot says why the run stopped
        failed = os.path.join(tempfile.mkdtemp(dir=self.folder), "a_failure_000009.h5")
        shutil.copy(self.paths[-1], failed)
        with h5py.File(failed, "r+") as f:
            f.attrs["failure"] = "health check: a fluid density outside the band"
        result = run("sph_snapshot.py", failed)
        self.assertIn("failure snapshot: health check: a fluid density", result.stdout)


class TestErrorTable(PostProcessingTestCase):

    def test_error_near_zero(self):
        for path, time in zip(self.paths[1:], TIMES[1:]):
            t, par, error, n = sph_error_table.snapshot_error(path)
            self.assertEqual(t, time)
            self.assertEqual(par["case"], self.case)
            self.assertGreater(n, 0)
            self.assertLess(error, 1e-12, path)

    def test_empty_selection_refused(self):
        # (it printed an error of 0 % for no particle at all)
        result = run("sph_error_table.py", "--level", "5", self.paths[-1])
        self.assertCleanFailure(result, "no fluid particle in the selection")

    def test_all_files_reported(self):
        # a file it cannot use among others: the others are still reported, the status is 1
        folder = tempfile.mkdtemp(prefix="sph_pp_table_")
        self.addCleanup(shutil.rmtree, folder, ignore_errors=True)
        bad = os.path.join(folder, "bad.h5")
        with open(bad, "wb") as f:
            f.write(b"not hdf5")
        result = run("sph_error_table.py", bad, self.paths[-1])
        self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
        self.assertIn(os.path.basename(self.paths[-1]), result.stdout)
        self.assertIn("bad.h5", result.stderr)

    def test_compare_nan_and_unreadable(self):
        # the same NaN in both files agrees (a failure snapshot and its copy differed); a NaN
        # against a number differs; an unreadable file is status 2, not a difference
        folder = tempfile.mkdtemp(prefix="sph_pp_compare_")
        try:
            a, b = (os.path.join(folder, name) for name in ("a.h5", "b.h5"))
            shutil.copy(self.paths[-1], a)
            with h5py.File(a, "r+") as f:
                f["particles/velocity"][0, 0] = np.nan
            shutil.copy(a, b)
            self.assertEqual(run("sph_compare.py", a, b).returncode, 0)
            self.assertEqual(run("sph_compare.py", a, self.paths[-1]).returncode, 1)
            with open(b, "wb") as f:
                f.write(b"not hdf5")
            result = run("sph_compare.py", a, b)
            self.assertEqual(result.returncode, 2, result.stdout + result.stderr)
            self.assertNotIn("Traceback", result.stderr)
        finally:
            shutil.rmtree(folder, ignore_errors=True)

    def test_compare_time_within_tolerance(self):
        # two runs' times a few ulps apart agree within a tolerance, not bitwise; far apart
        # they differ under any small tolerance
        folder = tempfile.mkdtemp(prefix="sph_pp_compare_time_")
        try:
            a, b = (os.path.join(folder, name) for name in ("a.h5", "b.h5"))
            shutil.copy(self.paths[-1], a)
            shutil.copy(self.paths[-1], b)
            with h5py.File(b, "r+") as f:
                f.attrs["time"] = np.nextafter(np.nextafter(f.attrs["time"], np.inf), np.inf)
            self.assertEqual(run("sph_compare.py", a, b).returncode, 1)
            self.assertEqual(run("sph_compare.py", a, b, "--tolerance", "1e-12").returncode, 0)
            with h5py.File(b, "r+") as f:
                f.attrs["time"] = 1.001 * f.attrs["time"] + 1.0
            self.assertEqual(run("sph_compare.py", a, b, "--tolerance", "1e-12").returncode, 1)
        finally:
            shutil.rmtree(folder, ignore_errors=True)

    def test_channel_parameters(self):
        par = sph_error_table.channel_parameters(sph_snapshot.load(self.paths[0])["input"])
        self.assertAlmostEqual(par["width"], 1e-3)
        self.assertAlmostEqual(par["nu"], 1e-6)
        self.assertAlmostEqual(par["dx"], 1e-4)
        if self.case == "couette":
            self.assertAlmostEqual(par["wall_speed"], 1e-5)
        else:
            self.assertAlmostEqual(par["force"], 2e-4)


class TestPlots(PostProcessingTestCase):

    def test_profile_plot_from_directory(self):
        out = os.path.join(self.folder, "profiles.png")
        result = run("sph_plot_profiles.py", self.folder, "--output", out)
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertTrue(is_png(out), out)
        self.assertIn("3 time(s)", result.stdout)

    def test_profile_plot_averaged_from_files(self):
        out = os.path.join(self.folder, "profiles_avg.png")
        result = run("sph_plot_profiles.py", *self.paths[1:3], "--average", "--steady", "-o", out)
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertTrue(is_png(out), out)
        self.assertIn("2 time(s)", result.stdout)

    def test_profile_plot_bad_input(self):
        out = os.path.join(self.folder, "never.png")
        self.assertCleanFailure(run("sph_plot_profiles.py", os.path.join(self.folder, "nope"),
                                    "-o", out), "nope")
        self.assertCleanFailure(run("sph_plot_profiles.py", self.paths[0], "-o", out),
                                "t > 0")
        self.assertFalse(os.path.exists(out))

    def test_field_plots(self):
        for field, kinds in (("velocity_x", "fluid,wall"), ("pressure", "fluid"),
                             ("velocity_magnitude", "all"), ("rank", "fluid,wall"),
                             ("kind", "fluid,wall"), ("density", "wall")):
            out = os.path.join(self.folder, f"field_{field}.png")
            result = run("sph_plot_field.py", self.paths[-1], "--field", field, "--kinds", kinds,
                         "--output", out)
            self.assertEqual(result.returncode, 0, field + ": " + result.stderr)
            self.assertTrue(is_png(out, 3000), out)

    def test_field_plot_bad_input(self):
        out = os.path.join(self.folder, "never.png")
        self.assertCleanFailure(run("sph_plot_field.py", self.paths[-1], "--field", "bogus",
                                    "-o", out), "unknown field 'bogus'")
        self.assertCleanFailure(run("sph_plot_field.py", self.paths[-1], "--kinds", "flud",
                                    "-o", out), "unknown kind 'flud'")
        self.assertCleanFailure(run("sph_plot_field.py", self.paths[-1], "--kinds", "virtual",
                                    "-o", out), "no particles")
        self.assertCleanFailure(run("sph_plot_field.py", os.path.join(self.folder, "x.h5"),
                                    "-o", out), "x.h5")
        self.assertFalse(os.path.exists(out))

    def test_help(self):
        for script in ("sph_snapshot.py", "sph_plot_profiles.py", "sph_plot_field.py",
                       "sph_check_xdmf.py"):
            result = run(script, "--help")
            self.assertEqual(result.returncode, 0, script)
            self.assertIn("usage:", result.stdout)


class TestPlotOptions(unittest.TestCase):
    """Options the plot scripts refuse with a message (a traceback or a broken colour bar
    before)."""

    def test_refused_options(self):
        for script, extra in (("sph_plot_field.py", ["--vmin", "1", "--vmax", "0"]),
                              ("sph_plot_field.py", ["--dpi", "0"]),
                              ("sph_plot_profiles.py", ["--dpi", "0"])):
            result = run(script, "no_such.h5", "-o", "x.png", *extra)
            self.assertEqual(result.returncode, 2, result.stdout + result.stderr)
            self.assertNotIn("Traceback", result.stderr)


class TestXdmf(PostProcessingTestCase):

    def broken_copy(self, old, new, count=1):
        with open(self.xdmf) as f:
            text = f.read()
        self.assertIn(old, text)
        path = os.path.join(self.folder, "broken.xdmf")
        with open(path, "w") as f:
            f.write(text.replace(old, new, count))
        self.addCleanup(os.remove, path)
        return path

    def test_good_file_passes(self):
        summary, problems = sph_check_xdmf.check(self.xdmf)
        self.assertEqual(problems, [])
        self.assertEqual(summary["grids"], len(TIMES))
        self.assertEqual(summary["items"], 11 * len(TIMES))
        self.assertEqual(summary["times"], list(TIMES))
        result = run("sph_check_xdmf.py", self.xdmf)
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertIn("OK: 4 time steps", result.stdout)

    def test_missing_dataset(self):
        path = self.broken_copy("/particles/density<", "/particles/no_such_field<")
        result = run("sph_check_xdmf.py", path)
        self.assertCleanFailure(result, "synthetic_000000.h5:/particles/no_such_field: "
                                        "no such dataset")

    def test_wrong_dimension(self):
        n = len(sph_snapshot.load(self.paths[0])["id"])
        path = self.broken_copy(f'Dimensions="{n}" NumberType="Float" Precision="8" '
                                'Format="HDF">synthetic_000000.h5:/particles/pressure',
                                f'Dimensions="{n + 1}" NumberType="Float" Precision="8" '
                                'Format="HDF">synthetic_000000.h5:/particles/pressure')
        result = run("sph_check_xdmf.py", path)
        self.assertCleanFailure(result, "synthetic_000000.h5:/particles/pressure",
                                f"Dimensions {n + 1} in the XDMF but shape {n} in the file")

    def test_missing_file(self):
        path = self.broken_copy("synthetic_001705.h5:/particles/position",
                                "gone_001705.h5:/particles/position")
        self.assertCleanFailure(run("sph_check_xdmf.py", path), "gone_001705.h5", "does not exist")

    def test_wrong_time(self):
        path = self.broken_copy(f'<Time Value="{TIMES[2]:24.16E}"/>', '<Time Value="0.3"/>')
        self.assertCleanFailure(run("sph_check_xdmf.py", path), "differs from the file's time")

    def test_times_not_increasing(self):
        path = self.broken_copy(f'<Time Value="{TIMES[3]:24.16E}"/>', '<Time Value="0.1"/>')
        self.assertCleanFailure(run("sph_check_xdmf.py", path), "times do not increase")

    def test_number_of_elements(self):
        n = len(sph_snapshot.load(self.paths[0])["id"])
        path = self.broken_copy(f'NumberOfElements="{n}"', f'NumberOfElements="{n - 1}"')
        self.assertCleanFailure(run("sph_check_xdmf.py", path), "NumberOfElements")

    def test_not_xml(self):
        self.assertCleanFailure(run("sph_check_xdmf.py", self.paths[0]), "not readable XML")
        self.assertCleanFailure(run("sph_check_xdmf.py", os.path.join(self.folder, "no.xdmf")),
                                "no such file")


class Test3DCouette(TestSnapshot, TestErrorTable, TestPlots, TestXdmf):
    """The same checks on a 3D Couette series (slice plots, u_x(y) over the whole depth)."""
    case, dim = "couette", 3

    def test_field_slice(self):
        out = os.path.join(self.folder, "slice.png")
        result = run("sph_plot_field.py", self.paths[-1], "--field", "velocity_x", "--z",
                     "0.25e-3", "-o", out)
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertTrue(is_png(out, 3000))
        n_layer = sum(np.abs(sph_snapshot.load(self.paths[-1])["position"][:, 2] - 0.25e-3) < 0.5e-4)
        self.assertIn(f"{n_layer} particles", result.stdout)


    def test_reference_of_a_fluid_at_rest_refused(self):
        # --case poiseuille on a Couette flow (no body force): the reference is 0 and the
        # velocities' norm was printed as a relative error ('0.0181%'); refused as the program
        # refuses a flow with no drive, also by the profile plot (the same function)
        with self.assertRaisesRegex(ValueError, "needs a body force"):
            sph_error_table.snapshot_error(self.paths[-1], "poiseuille")
        result = run("sph_error_table.py", "--case", "poiseuille", self.paths[-1])
        self.assertCleanFailure(result, "needs a body force", self.paths[-1])
        self.assertNotIn("%", result.stdout)
        out = os.path.join(self.folder, "never_at_rest.png")
        self.assertCleanFailure(call_main("sph_plot_profiles", "--case", "poiseuille",
                                          self.paths[-1], "-o", out), "needs a body force")
        self.assertFalse(os.path.exists(out))


class TestSpacingAttribute(unittest.TestCase):
    """The spacing of level 0 comes from a file's root attribute dx where it has one (after an
    in-run remesh its stored input keeps the spacing the run began with: a refined channel
    was reported at the starting dx/L), else from the input's &domain dx; one function of
    the loader, used by every script."""

    @classmethod
    def setUpClass(cls):
        cls.folder = tempfile.mkdtemp(prefix="sph_pp_spacing_")
        width, dx, nu, force = 1.0e-3, 1.0e-4, 1.0e-6, 2.0e-4
        box_hi = (0.3e-3, width, 0.0)
        text = input_text("poiseuille", 2, box_hi, dx, nu, force, 0.0)
        # the run refined once: particles at dx/2, the input still says dx
        pos, kind = lattice(2, box_hi, dx / 2)
        vel = np.zeros_like(pos)
        fluid = kind == 0
        vel[fluid, 0] = sph_analytic.poiseuille(pos[fluid, 1], 0.5, force, width, nu)
        cls.plain = os.path.join(cls.folder, "plain_000010.h5")
        cls.refined = os.path.join(cls.folder, "refined_000010.h5")
        for path in (cls.plain, cls.refined):
            write_snapshot(path, time=0.5, step=10, dim=2, text=text, pos=pos, kind=kind,
                           vel=vel)
        with h5py.File(cls.refined, "r+") as f:
            f.attrs["dx"] = np.float64(dx / 2)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.folder, ignore_errors=True)

    def test_loader(self):
        for path, dx in ((self.plain, 1.0e-4), (self.refined, 0.5e-4)):
            snap = sph_snapshot.load(path)
            self.assertEqual(sph_snapshot.spacing(snap), dx, path)
            self.assertEqual(sph_snapshot.spacing(sph_snapshot.header(path)), dx, path)
            self.assertEqual(sph_snapshot.geometry(snap)["dx"], dx, path)
        result = run("sph_snapshot.py", self.refined)
        self.assertIn("dx 5e-05 m", result.stdout, result.stderr)

    def test_bad_attribute_refused(self):
        snap = sph_snapshot.load(self.refined)
        for bad in (0.0, -1e-4, float("nan"), "5e-5"):
            snap["attrs"]["dx"] = bad
            with self.assertRaisesRegex(ValueError, "root attribute dx"):
                sph_snapshot.spacing(snap)

    def test_scripts(self):
        import body_drag
        import cavity_ghia
        import sph_interface_profile
        par = sph_error_table.snapshot_error(self.refined)[1]
        self.assertEqual(par["dx"], 0.5e-4, "sph_error_table (and sph_plot_profiles)")
        self.assertEqual(sph_error_table.snapshot_error(self.plain)[1]["dx"], 1.0e-4)
        result = run("sph_error_table.py", self.refined)
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertIn(" 0.0500 ", result.stdout, "dx/L of the refined file")
        self.assertEqual(sph_interface_profile.load(self.refined)["dx"], 0.5e-4)
        self.assertEqual(body_drag.input_and_spacing([(0.5, self.refined)])[1], 0.5e-4)
        self.assertEqual(cavity_ghia.input_and_spacing(self.refined)[1], 0.5e-4)
        self.assertEqual(cavity_ghia.input_and_spacing(self.plain)[1], 1.0e-4)

    def test_profile_plot_of_a_remeshed_run(self):
        # one set-up at two spacings: a note, not "different set-ups"; the title's dx/L the
        # last file's
        out = os.path.join(self.folder, "remeshed.png")
        result = call_main("sph_plot_profiles", self.plain, self.refined, "--average",
                           "--dpi", "20", "-o", out)
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertIn("spacings differ", result.stderr)
        self.assertNotIn("different set-ups", result.stderr)


class TestLoaderChecksEverywhere(ScriptTestCase):
    """sph_error_table, sph_interface_profile and sph_compare read files through the loader's
    checks: a file without write_complete was used silently, a directory gave h5py's errno
    dump, another tool's file "can't locate attribute 'time'", and sph_compare said 'agree'
    with a file that has no velocity. Each is now one message naming the file and the
    problem, with a non-zero status."""

    @classmethod
    def setUpClass(cls):
        cls.folder = tempfile.mkdtemp(prefix="sph_pp_checks_")
        box_hi = (0.3e-3, 1.0e-3, 0.0)
        text = input_text("poiseuille", 2, box_hi, 1.0e-4, 1.0e-6, 2.0e-4, 0.0)
        pos, kind = lattice(2, box_hi, 1.0e-4)
        vel = np.zeros_like(pos)
        vel[kind == 0, 0] = 1e-5
        cls.good = os.path.join(cls.folder, "good_000010.h5")
        incomplete = os.path.join(cls.folder, "incomplete_000010.h5")
        for path, complete in ((cls.good, True), (incomplete, False)):
            write_snapshot(path, time=0.5, step=10, dim=2, text=text, pos=pos, kind=kind,
                           vel=vel, complete=complete)
        foreign = os.path.join(cls.folder, "foreign.h5")
        with h5py.File(foreign, "w") as f:
            f["x"] = np.arange(3.0)
        novelocity = os.path.join(cls.folder, "novelocity.h5")
        shutil.copy(cls.good, novelocity)
        with h5py.File(novelocity, "r+") as f:
            del f["particles/velocity"]
        directory = os.path.join(cls.folder, "a_folder")
        os.mkdir(directory)
        cls.cases = ((incomplete, "incomplete snapshot (no write_complete marker)"),
                     (directory, "a directory, not a snapshot file"),
                     (foreign, "not a sphremesh snapshot or checkpoint"),
                     (novelocity, "/particles lacks velocity"))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.folder, ignore_errors=True)

    def test_error_table(self):
        for path, message in self.cases:
            result = call_main("sph_error_table", path)
            self.assertEqual(result.returncode, 1, path + ": " + result.stderr)
            self.assertIn(f"{path}: {message}", result.stderr)
        self.assertEqual(call_main("sph_error_table", self.good).returncode, 0)

    def test_interface_profile(self):
        for path, message in self.cases:
            result = call_main("sph_interface_profile", path)
            self.assertEqual(result.returncode, 1, path + ": " + result.stderr)
            self.assertIn(f"{path}: {message}", result.stderr)

    def test_interface_profile_names_a_missing_uniform_file(self):
        # a uniform run's file that does not exist was reported as a problem of the figure
        # ("the figure 'i2.png': ... nonexist.h5"), after the table
        missing = os.path.join(self.folder, "nonexist.h5")
        figure = os.path.join(self.folder, "i2.png")
        result = call_main("sph_interface_profile", self.good, missing, "--figure", figure,
                           "--interfaces", "0.5e-3")
        self.assertCleanFailure(result, f"{missing}: no such file")
        self.assertNotIn("figure", result.stderr)
        self.assertFalse(os.path.exists(figure))

    def test_compare(self):
        for path, message in self.cases:
            for pair in ((self.good, path), (path, self.good)):
                result = call_main("sph_compare", *pair)
                self.assertEqual(result.returncode, 2, path + ": " + result.stderr)
                self.assertIn(f"{path}: {message}", result.stderr)
                self.assertNotIn("agree", result.stdout)
        result = run("sph_compare.py", self.good, self.cases[1][0])
        self.assertEqual(result.returncode, 2, result.stderr)
        self.assertNotIn("Traceback", result.stderr)
        self.assertNotIn("agree", result.stdout)
        self.assertEqual(result.stderr.strip().count("\n"), 0, "one line")

    def test_compare_tolerance_refused(self):
        # a negative or non-finite tolerance was taken, and the file then DIFFERed from itself
        for bad in ("-1", "nan", "inf"):
            result = call_main("sph_compare", self.good, self.good, "--tolerance", bad)
            self.assertEqual(result.returncode, 2, bad + ": " + result.stderr)
            self.assertIn("--tolerance must be a finite number >= 0", result.stderr)
        result = call_main("sph_compare", self.good, self.good, "--tolerance", "0")
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertIn("agree", result.stdout)

    def test_snapshot_folder_goes_on(self):
        # a folder whose first file is cut short: reported, and the others summarised (the
        # summary stopped at it)
        folder = os.path.join(self.folder, "run")
        os.makedirs(folder, exist_ok=True)
        shutil.copy(self.good, os.path.join(folder, "case_000020.h5"))
        with open(self.good, "rb") as f:
            head = f.read(2000)
        with open(os.path.join(folder, "case_000001.h5"), "wb") as f:
            f.write(head)
        result = call_main("sph_snapshot", folder)
        self.assertEqual(result.returncode, 1, result.stderr)
        self.assertIn("case_000001.h5: not a readable HDF5 file", result.stderr)
        self.assertIn("case_000020.h5", result.stdout)
        self.assertIn("time 0.5 s, step 10", result.stdout)


class TestCouettePoiseuille(unittest.TestCase):
    """A Couette channel with a body force along the plate's motion: the reference is the sum
    of both series, as the program's (it was the Couette series alone: 37 % on a flow the
    run got right)."""

    def test_steady_sum(self):
        par = {"width": 1.0e-3, "nu": 1.0e-6, "wall_speed": 2.5e-5, "force": 1.0e-4}
        y = np.linspace(0.0, 1.0e-3, 11)
        exact = (2.5e-5 * y / 1.0e-3 + 1.0e-4 / (2 * 1.0e-6) * y * (1.0e-3 - y))
        np.testing.assert_allclose(sph_analytic.channel("couette", y, np.inf, par), exact,
                                   rtol=0, atol=1e-18)

    def test_transient_sum(self):
        par = {"width": 1.0e-3, "nu": 1.0e-6, "wall_speed": 2.5e-5, "force": 1.0e-4}
        y = np.linspace(0.0, 1.0e-3, 11)
        both = sph_analytic.channel("couette", y, 0.02, par)
        parts = (sph_analytic.couette(y, 0.02, 2.5e-5, 1.0e-3, 1.0e-6)
                 + sph_analytic.poiseuille(y, 0.02, 1.0e-4, 1.0e-3, 1.0e-6))
        np.testing.assert_allclose(both, parts, rtol=0, atol=1e-18)
        self.assertGreater(np.max(np.abs(both - sph_analytic.couette(
            y, 0.02, 2.5e-5, 1.0e-3, 1.0e-6))), 1e-6)
        self.assertIsNone(sph_analytic.channel("none", y, 0.02, par))


class TestChannelAxes(unittest.TestCase):
    """A channel on any axis, with either wall moving, is found as the program finds it (the
    scripts took walls on y and the upper plate moving: for the others they printed the
    velocities' norm as a relative error, 0.01 % where the program's log said 0.54 %)."""

    @staticmethod
    def text(domain, fluid, analytic, moving_face=None):
        """As the resolved input stored in a file (every element of wall_velocity given)."""
        wall = np.zeros((6, 3))
        if moving_face is not None:
            wall[moving_face, 0] = 2.5e-5
        walls = ", ".join(f"{v:.17g}" for v in wall.ravel())
        return (f"&run analytic='{analytic}' /\n&domain dimension=2, box_lo=0.0, 0.0, 0.0, "
                f"box_hi=1.0e-3, 0.5e-3, 1.0, dx=2.5e-5, {domain}, wall_velocity={walls} /\n"
                f"&fluid nu=1.0e-6, body_force={fluid} /\n")

    def test_walls_on_x_flow_along_y(self):
        par = sph_error_table.channel_parameters(self.text(
            "boundary='wall','wall','periodic','periodic','periodic','periodic'",
            "0.0, 2.0e-4, 0.0", "poiseuille"))
        self.assertEqual((par["axis"], par["flow"], par["sign"]), (0, 1, 1.0))
        self.assertAlmostEqual(par["width"], 1.0e-3)
        self.assertAlmostEqual(par["force"], 2.0e-4)
        y = sph_error_table.wall_distance(par, np.array([[0.25e-3, 0.1e-3, 0.0]]))
        self.assertAlmostEqual(y[0], 0.25e-3)

    def test_lower_wall_moving(self):
        par = sph_error_table.channel_parameters(self.text(
            "boundary='periodic','periodic','wall','wall','periodic','periodic'", "0.0, 0.0, 0.0",
            "couette", moving_face=2))
        self.assertEqual((par["axis"], par["flow"], par["sign"]), (1, 0, -1.0))
        self.assertAlmostEqual(par["wall_speed"], 2.5e-5)
        # the distance from the resting (upper) wall: the moving one at the full width
        y = sph_error_table.wall_distance(par, np.array([[0.0, 0.0, 0.0], [0.0, 0.5e-3, 0.0]]))
        np.testing.assert_allclose(y, [0.5e-3, 0.0], atol=1e-18)

    def test_case_given_on_the_command_line(self):
        # an input with analytic = 'none' and --case couette: the drive is the moving wall
        # (the velocities' norm was printed as the relative error)
        for face, sign in ((3, 1.0), (2, -1.0)):
            par = sph_error_table.channel_parameters(self.text(
                "boundary='periodic','periodic','wall','wall','periodic','periodic'",
                "0.0, 0.0, 0.0", "none", moving_face=face), "couette")
            self.assertEqual((par["case"], par["sign"]), ("couette", sign))
            self.assertAlmostEqual(par["wall_speed"], 2.5e-5)

    def test_not_a_channel(self):
        par = sph_error_table.channel_parameters(self.text(
            "boundary='wall','wall','wall','wall','periodic','periodic'", "0.0, 0.0, 0.0", "none"))
        self.assertIsNone(par["axis"])


class TestMakeInitialParticles(unittest.TestCase):
    """make_initial_particles.py never replaces a file without --force (-o INPUT.nml wrote
    over the input), and puts array elements given from an index where they belong."""

    def setUp(self):
        self.folder = tempfile.mkdtemp(prefix="sph_maker_")
        self.addCleanup(shutil.rmtree, self.folder, ignore_errors=True)
        source = os.path.join(ROOT, "tests", "regression", "poiseuille_short.nml")
        with open(source) as f:
            self.text = f.read()
        self.input = os.path.join(self.folder, "in.nml")
        with open(self.input, "w") as f:
            f.write(self.text)

    def test_existing_output_is_kept(self):
        result = run("make_initial_particles.py", self.input, "-o", self.input)
        self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
        self.assertIn("exists; give another name, or --force", result.stderr)
        with open(self.input) as f:
            self.assertEqual(f.read(), self.text)

    def test_missing_folder_is_named(self):
        out = os.path.join(self.folder, "no_such_folder", "p.h5")
        result = run("make_initial_particles.py", self.input, "-o", out)
        self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
        self.assertIn("does not exist", result.stderr)
        self.assertNotIn("Traceback", result.stderr)

    def test_output_directory_refused(self):
        # -o a folder with --force ended in an IsADirectoryError traceback
        for extra in ((), ("--force",)):
            result = call_main("make_initial_particles", self.input, "-o", self.folder, *extra)
            self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
            self.assertIn("is a directory; give the file to write", result.stderr)
            self.assertNotIn("Traceback", result.stderr)
        self.assertTrue(os.path.isdir(self.folder))

    def test_elements_from_an_index(self):
        indexed = os.path.join(self.folder, "indexed.nml")
        with open(indexed, "w") as f:
            f.write(self.text.replace("boundary = 'periodic', 'periodic', 'wall', 'wall'",
                                      "boundary(3:4) = 'wall', 'wall'"))
        counts = []
        for name in (self.input, indexed):
            out = name + ".h5"
            result = run("make_initial_particles.py", name, "-o", out)
            self.assertEqual(result.returncode, 0, result.stdout + result.stderr)
            with h5py.File(out, "r") as f:
                counts.append(int((f["particles/kind"][()] == 1).sum()))
        self.assertEqual(counts[0], counts[1], "the walls on the same faces")


class TestBodyDragReference(unittest.TestCase):
    """The reference of one circle in a square cell holds with a refinement region around
    it: a &region's shape = 'body' is no second body (the reference was left out)."""

    def test_region_around_the_body(self):
        import body_drag
        body = "&body\n    shape = 'circle'\n    radius = 0.02\n/\n"
        region = "&region\n    shape = 'body'\n    distance = 0.01\n/\n"
        lo, hi = [0.0, 0.0], [0.1, 0.1]
        alone = body_drag.sangani_acrivos_speed(body, 2, lo, hi, 1e-7, 1e-6, 1000.0)
        banded = body_drag.sangani_acrivos_speed(body + region, 2, lo, hi, 1e-7, 1e-6, 1000.0)
        self.assertIsNotNone(alone)
        self.assertEqual(alone, banded)


class TestBodyDragTimeAverage(unittest.TestCase):
    """body_drag.time_averaged: the rows' step means weighted by the time each covers."""

    def test_weights_by_interval(self):
        import body_drag
        rows = [{"time": "0.0", "Fx_mean": "5.0"}, {"time": "1.0", "Fx_mean": "1.0"},
                {"time": "4.0", "Fx_mean": "2.0"}, {"time": "5.0", "Fx_mean": "6.0"}]
        # the last three rows cover 1, 3 and 1 s: (1 + 6 + 6) / 5
        self.assertAlmostEqual(body_drag.time_averaged(rows, rows[1:], "Fx_mean", "run"),
                               13.0 / 5.0)
        # a run's first row covers no time: alone it is refused
        with self.assertRaises(SystemExit):
            body_drag.time_averaged(rows[:1], rows[:1], "Fx_mean", "run")

    def test_missing_column_refused(self):
        import body_drag
        rows = [{"time": "0.0", "Fx": "1.0"}, {"time": "1.0", "Fx": "1.0"}]
        with self.assertRaises(SystemExit) as caught:
            body_drag.time_averaged(rows, rows, "Fx_mean", "run")
        self.assertIn("no Fx_mean column", str(caught.exception))


class TestFractionRefused(unittest.TestCase):
    """cavity_ghia.py --fraction outside (0, 1] is refused before any file is read, as by
    body_drag.py (2 and 0 were taken)."""

    def test_out_of_range(self):
        for bad in ("2", "0", "-0.5", "nan"):
            result = call_main("cavity_ghia", "no_such_folder", "--fraction", bad)
            self.assertEqual(result.returncode, 2, bad + ": " + result.stderr)
            self.assertIn("--fraction must lie in (0, 1]", result.stderr)
        # 1 is allowed: the run's whole time (then the missing folder is the problem)
        result = call_main("cavity_ghia", "no_such_folder", "--fraction", "1")
        self.assertNotIn("--fraction", result.stderr)
        self.assertIn("no_such_folder", result.stderr)


class TestBodyDragCaseName(unittest.TestCase):
    """body_drag.case_of: each run directory's case from its one forces file, so runs of
    different inputs compare in one call."""

    def test_inferred_given_and_refused(self):
        import body_drag
        with tempfile.TemporaryDirectory() as tmp:
            with self.assertRaises(SystemExit) as caught:
                body_drag.case_of(tmp, None)
            self.assertIn("--case", str(caught.exception))
            open(os.path.join(tmp, "cylinder_multires_forces.csv"), "w").close()
            self.assertEqual(body_drag.case_of(tmp, None), "cylinder_multires")
            self.assertEqual(body_drag.case_of(tmp, "other"), "other")
            open(os.path.join(tmp, "cylinder_forces.csv"), "w").close()
            with self.assertRaises(SystemExit):
                body_drag.case_of(tmp, None)


class TestRowMeansPerLevel(unittest.TestCase):
    """sph_plot_profiles --average: each level's rows at its own spacing."""

    def test_fine_rows_kept_apart(self):
        os.environ.setdefault("MPLBACKEND", "Agg")
        import sph_plot_profiles
        dx = 1e-4
        coarse = (np.arange(10) + 0.5) * dx                  # rows of the coarse level
        fine = 0.3e-3 + (np.arange(4) + 0.5) * dx / 2        # a band of level 1 at dx/2
        coarse = coarse[(coarse < 0.3e-3) | (coarse > 0.5e-3)]
        y = np.concatenate([np.repeat(coarse, 5), np.repeat(fine, 10)])
        u = y * 2.0
        level = np.concatenate([np.zeros(5 * len(coarse), int), np.ones(10 * len(fine), int)])
        ym, um, us = sph_plot_profiles.level_row_means(y, u, level, dx)
        np.testing.assert_allclose(ym, np.sort(np.concatenate([coarse, fine])), rtol=1e-12)
        np.testing.assert_allclose(um, 2.0 * ym, rtol=1e-12)
        self.assertTrue(np.all(us < 1e-12))


class TestDamagedRunFolder(unittest.TestCase):
    """A run folder with a snapshot cut short (a copy or a disk that filled), an unfinished
    one and a forces file that is missing or ends in a short row: the reading scripts skip
    what they cannot read, each with one line, and answer from the rest, or refuse in one
    line; never a traceback."""

    CYLINDER = """
&body
    name = 'cylinder'
    shape = 'circle'
    centre = 0.25e-3, 0.5e-3, 0.0
    radius = 1.0e-4
/
"""

    def setUp(self):
        self.folder = tempfile.mkdtemp(prefix="sph_pp_damaged_")
        text = input_text("poiseuille", 2, (0.5e-3, 1.0e-3, 0.0), 1e-4, 1e-6, 2e-4, 0.0)
        self.text = text + self.CYLINDER
        pos, kind = lattice(2, (0.5e-3, 1.0e-3, 0.0), 1e-4)
        vel = np.zeros_like(pos)
        vel[kind == 0, 0] = 1e-5
        for step, time in ((10, 1.0), (20, 2.0), (30, 3.0), (40, 4.0)):
            write_snapshot(os.path.join(self.folder, f"cyl_{step:06d}.h5"), time=time,
                           step=step, dim=2, text=self.text, pos=pos, kind=kind, vel=vel,
                           complete=step != 30)
        # the newest snapshot cut short: h5py cannot open it
        newest = os.path.join(self.folder, "cyl_000040.h5")
        with open(newest, "rb") as f:
            head = f.read(os.path.getsize(newest) // 3)
        with open(newest, "wb") as f:
            f.write(head)

    def tearDown(self):
        shutil.rmtree(self.folder, ignore_errors=True)

    def write_forces(self, last_row_short):
        rows = ["step,time,body,Fx,Fy,Fz", "10,1.0,cylinder,1e-9,0,0",
                "20,2.0,cylinder,1e-9,0,0", "40,4.0,cylinder,1e-9,0,0"]
        if last_row_short:
            rows.append("50,5.0,cylinder,1e-9")
        with open(os.path.join(self.folder, "cyl_forces.csv"), "w") as f:
            f.write("\n".join(rows) + "\n")

    def test_complete_snapshots_skip_damaged(self):
        found = sph_snapshot.complete_snapshots(self.folder, "cyl", "test")
        self.assertEqual([t for t, _ in found], [1.0, 2.0])
        with self.assertRaises(ValueError):
            sph_snapshot.complete_snapshots(os.path.join(self.folder, "no"), "cyl", "test")

    def test_body_drag(self):
        result = run("body_drag.py", self.folder, "--case", "cyl")
        self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
        self.assertNotIn("Traceback", result.stderr)
        self.assertIn("cannot read", result.stderr)
        self.assertIn("cyl_forces.csv", result.stderr)
        self.write_forces(last_row_short=True)
        result = run("body_drag.py", self.folder, "--case", "cyl")
        self.assertEqual(result.returncode, 0, result.stdout + result.stderr)
        self.assertIn("skipped", result.stderr)
        self.assertIn("cyl_000040.h5", result.stderr)
        self.assertIn("short row", result.stderr)
        self.assertIn("mean fluid velocity 1.000000e-05", result.stdout)

    def test_body_drag_figure(self):
        # a forces file without the step means (older runs): the rows' forces are drawn
        self.write_forces(last_row_short=False)
        figure = os.path.join(self.folder, "drag.png")
        result = run("body_drag.py", self.folder, "--case", "cyl", "--figure", figure,
                     "--labels", "one run")
        self.assertEqual(result.returncode, 0, result.stdout + result.stderr)
        self.assertIn(f"wrote {figure}", result.stdout)
        with open(figure, "rb") as f:
            self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n")
        for bad, words in ((["--labels", "a,b"], "--labels names 2 runs, 1 are given"),
                           (["--figure", os.path.join(self.folder, "drag.pdf")], ".png")):
            result = run("body_drag.py", self.folder, "--case", "cyl", "--figure", figure,
                         *bad)
            self.assertEqual(result.returncode, 2, result.stdout + result.stderr)
            self.assertIn(words, result.stderr)
            self.assertNotIn("Traceback", result.stderr)

    def test_interface_profile_options_between_files(self):
        # uniform snapshots after an option are files, not "unrecognized arguments"
        missing = os.path.join(self.folder, "missing.h5")
        result = run("sph_interface_profile.py", missing, "--figure",
                     os.path.join(self.folder, "f.png"), os.path.join(self.folder, "u.h5"))
        self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
        self.assertIn("missing.h5", result.stderr)
        self.assertNotIn("unrecognized", result.stderr)
        self.assertNotIn("Traceback", result.stderr)

    def test_cavity_ghia(self):
        result = run("cavity_ghia.py", self.folder, "--case", "cyl", "--min-snapshots", "1")
        self.assertNotIn("Traceback", result.stderr)
        self.assertIn("skipped", result.stderr)
        self.assertIn("cyl_000040.h5", result.stderr)
        # this input has no moving lid: refused in one line after the snapshots were read
        self.assertIn("moving upper face", result.stderr)


if __name__ == "__main__":
    unittest.main()
