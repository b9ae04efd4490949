#!/usr/bin/env python3
"""Run the validation cases, regenerate the figures and tables of doc/validation.md (and the
README's accuracy table) from those runs, and fail loudly when an error exceeds its limit.

    scripts/validate [--only CASE ...] [--skip-long] [--reuse] [--np 2] [--work DIR]
    scripts/validate --list

Each case runs the shipped inputs (input/*.nml), with the namelist keys the case overrides
(resolution, end time, output folder) written into a copy under the work folder
(default validation-runs/), then measures the runs with the post-processing scripts
(sph_error_table, cavity_ghia, body_drag, sph_interface_profile) and writes:
  - a Markdown block between `<!-- validate:NAME -->` and `<!-- /validate:NAME -->` in
    doc/validation.md (README.md for the accuracy table), with each figure, its limit and
    whether it held;
  - the case's figures in doc/.
Limits are what the documentation claims (a run that does worse fails); where an issue sets
a stricter target that is not met yet, the block says so without failing.
--reuse measures existing runs again without running them; --skip-long leaves out the cases
marked long (hours on a workstation: the Re = 1000 cavity, the L/100 cavity and the L/100
cylinder).
Exit status: 0 all limits held, 1 a limit was exceeded or a run failed, 2 bad usage.
"""
import argparse
import datetime
import glob
import os
import re
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

# --help and --list need none of the measuring tools: scripts/validate runs them with any
# python3, before install-deps has made the venv (numpy, h5py)
try:
    import numpy as np
    import sph_analytic
    import sph_error_table
    import sph_snapshot
    MISSING_TOOLS = None
except ImportError as exc:
    MISSING_TOOLS = exc

PYTHON = sys.executable


# ----------------------------------------------------------------------------- namelists

def fortran_value(value):
    """A Python value as a namelist literal."""
    if isinstance(value, bool):
        return ".true." if value else ".false."
    if isinstance(value, str):
        return "'" + value + "'"
    if isinstance(value, (list, tuple)):
        return ", ".join(fortran_value(v) for v in value)
    if isinstance(value, float):
        return repr(value)
    return str(value)


def set_keys(text, group, values):
    """The namelist text with `key = value` set in &group (replaced where the key is, else
    added before the group's closing /); the group is added when missing."""
    lines = text.splitlines()
    start = next((k for k, line in enumerate(lines)
                  if line.strip().lower().startswith("&" + group.lower())), None)
    if start is None:
        lines += ["&" + group] + [f"    {k} = {fortran_value(v)}" for k, v in values.items()]
        lines.append("/")
        return "\n".join(lines) + "\n"
    end = next(k for k in range(start + 1, len(lines)) if lines[k].strip() == "/")
    for key, value in values.items():
        pattern = re.compile(r"^\s*" + re.escape(key) + r"\s*=", re.IGNORECASE)
        found = [k for k in range(start + 1, end) if pattern.match(lines[k])]
        line = f"    {key} = {fortran_value(value)}"
        if found:
            lines[found[0]] = line
            for k in reversed(found[1:]):
                del lines[k]
                end -= 1
        else:
            lines.insert(end, line)
            end += 1
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- running

class Runner:
    """Runs sphremesh on copies of the shipped inputs under the work folder."""

    def __init__(self, work, nranks, reuse, binary):
        self.work = work
        self.nranks = nranks
        self.reuse = reuse
        self.binary = binary
        self.failures = []
        self.finished = set()   # runs made by this invocation: later cases reuse them
        self.ranks_of = {}      # each run's rank count: one folder, one count
        self.commits = set()    # the program's commits that made the runs a case read

    def note_version(self, log):
        """Add the commit of the program that wrote `log` (its first line, 'sphremesh
        VERSION (git HASH) ...') to self.commits: a block measured with --reuse says which
        build made its runs, not only the commit that measured them."""
        try:
            with open(log) as f:
                found = re.search(r"\(git ([0-9a-f]{7})[0-9a-f]*", f.readline())
        except OSError:
            found = None
        self.commits.add(found.group(1) if found else "unknown")

    def relative(self, text):
        """A script's output as a block quotes it: the work folder's path left out of the
        runs' paths (the blocks name the runs, not the machine's folders), and without the
        lines naming the figures written (the block links them)."""
        return "\n".join(line for line in text.replace(self.work + os.sep, "").splitlines()
                         if not line.startswith("body_drag: wrote"))

    def run(self, name, source, overrides, nranks=None, restart=None):
        """Run input/`source` with `overrides` {group: {key: value}} as work/name (from the
        checkpoint `restart` if given); returns the output folder (None when the run failed).
        With --reuse a finished run is kept. A run is reused only when it was made from
        the same input on the same number of ranks (validate.done records both): a chaotic
        flow differs in its details between rank counts. One name has one rank count
        (ValueError otherwise): the cylinder lattice's serial runs are cylinder_L25_np1 and
        cylinder_L50_np1, the remeshing cases' runs on the default count cylinder_L25 and
        cylinder_L50."""
        np_ = nranks or self.nranks
        # a folder shared by runs on different rank counts was run again by each, the one
        # measured last replacing the other's (and --reuse ran both again every time): the
        # serial runs have names of their own (_np1)
        if self.ranks_of.setdefault(name, np_) != np_:
            raise ValueError(f"validate: the run {name} is asked on {self.ranks_of[name]} and "
                             f"on {np_} ranks; give one of them another name")
        out = os.path.join(self.work, name)
        done = os.path.join(out, "validate.done")
        with open(os.path.join(ROOT, "input", source)) as f:
            text = f.read()
        overrides = dict(overrides)
        overrides.setdefault("output", {})
        overrides["output"] = dict(overrides["output"], output_dir=out)
        for group, values in overrides.items():
            text = set_keys(text, group, values)
        stamp = f"ranks {np_}\nrestart {restart}\n{text}"
        log_path = os.path.join(self.work, name + ".log")
        if (self.reuse or name in self.finished) and os.path.exists(done):
            with open(done) as f:
                if f.read() == stamp:
                    self.note_version(log_path)
                    return out
        os.makedirs(out, exist_ok=True)
        nml = os.path.join(self.work, name + ".nml")
        with open(nml, "w") as f:
            f.write(text)
        for old in os.listdir(out):
            if old.endswith(".h5") or old.endswith(".csv") or old.endswith(".xdmf"):
                os.remove(os.path.join(out, old))
        cmd = ["mpirun", "-np", str(np_)]
        if np_ > (os.cpu_count() or 1):
            cmd.append("--oversubscribe")
        cmd += [self.binary, nml]
        if restart:
            cmd += ["--restart", restart]
        print(f"validate: running {name} ({' '.join(cmd[1:3])})", flush=True)
        with open(log_path, "w") as log:
            status = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
        self.note_version(log_path)
        if status != 0:
            self.failures.append(f"{name}: sphremesh exited with {status} "
                                 f"(log {os.path.join(self.work, name + '.log')})")
            return None
        with open(done, "w") as f:
            f.write(stamp)
        self.finished.add(name)
        return out


def script(name, *args):
    """Run one of the post-processing scripts; (exit status, stdout)."""
    result = subprocess.run([PYTHON, os.path.join(HERE, name)] + [str(a) for a in args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return result.returncode, result.stdout


def snapshots_at(out, times):
    """The snapshot of `out` nearest each time."""
    files = sph_snapshot.list_snapshots(out)
    found = []
    for t in times:
        best = min(files, key=lambda f: abs(sph_snapshot.load(f)["time"] - t))
        found.append(best)
    return found


# ----------------------------------------------------------------------------- results

class Block:
    """A generated Markdown block and the limits checked for it."""

    def __init__(self, name):
        self.name = name
        self.lines = []
        self.failed = []

    def check(self, what, value, limit, unit="%"):
        """One measured figure against its limit; returns the table cell text."""
        ok = value is not None and np.isfinite(value) and value <= limit
        if not ok:
            self.failed.append(f"{self.name}: {what} = {value} {unit} exceeds {limit} {unit}")
        return "yes" if ok else "**NO**"


def l2_percent(snapshot, case, **restrict):
    """Relative L2 velocity error of a snapshot in percent (sph_error_table's measure)."""
    return 100.0 * sph_error_table.snapshot_error(snapshot, case, **restrict)[2]


def snapshot_time(path):
    """The simulated time of a snapshot file."""
    return float(np.ravel(sph_snapshot.load(path)["attrs"]["time"])[0])


def pyplot(block):
    """matplotlib's pyplot on the file backend, or None with the block's failure noted (the
    figures are part of what validate regenerates)."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import matplotlib.ticker  # noqa: F401 (plt.matplotlib.ticker for the log axes)
    except ImportError:
        block.failed.append(f"{block.name}: matplotlib missing for the figure")
        return None
    return plt


def percent(x):
    return f"{x:.3g} %" if x is not None else "n/a"


# ----------------------------------------------------------------------------- the cases

CHANNEL_TIMES = (0.0225, 0.225, 1.0, 2.0)
# limits of the README's accuracy table: percent at 0.0225 / 0.225 / 1 / 2 s
CHANNEL_LIMITS = {
    ("poiseuille", 20): (1.0, 0.5, 0.6, 0.6),
    ("poiseuille", 40): (0.25, 0.13, 0.21, 0.3),
    ("poiseuille", 80): (0.07, 0.04, 0.17, 0.3),
    ("couette", 20): (0.85, 0.09, 0.02, 0.025),
    ("couette", 40): (0.21, 0.02, 0.016, 0.016),
    ("couette", 80): (0.055, 0.0055, 0.015, 0.015),
    ("poiseuille_3d", 40): (0.25, 0.12, 0.15, 0.24),
}
# the same with &numerics wall_extrapolation = 'quadratic' (physics.md, Walls)
CHANNEL_LIMITS_QUADRATIC = {
    ("poiseuille", 20): (0.26, 0.09, 0.14, 0.26),
    ("poiseuille", 40): (0.08, 0.03, 0.15, 0.28),
    ("poiseuille", 80): (0.022, 0.02, 0.16, 0.3),
    ("couette", 20): (0.36, 0.034, 0.02, 0.023),
    ("couette", 40): (0.1, 0.009, 0.016, 0.016),
    ("couette", 80): (0.027, 0.0047, 0.015, 0.015),
    ("poiseuille_3d", 40): (0.075, 0.028, 0.13, 0.32),
}
# and with density_filter = 'shepard' besides (physics.md, Known behaviour)
CHANNEL_LIMITS_SHEPARD = {
    ("poiseuille", 20): (0.26, 0.09, 0.014, 0.08),
    ("poiseuille", 40): (0.08, 0.025, 0.012, 0.075),
    ("poiseuille", 80): (0.022, 0.007, 0.012, 0.07),
    ("couette", 20): (0.36, 0.034, 0.07, 0.012),
    ("couette", 40): (0.1, 0.016, 0.008, 0.011),
    ("couette", 80): (0.027, 0.022, 0.015, 0.018),
    ("poiseuille_3d", 40): (0.075, 0.024, 0.06, 0.3),
}
# the channel case's numerics: (name, &numerics settings, title suffix, limits)
CHANNEL_NUMERICS = (
    ("linear", {}, "", CHANNEL_LIMITS),
    ("quadratic", {"wall_extrapolation": "quadratic"}, ", quadratic walls",
     CHANNEL_LIMITS_QUADRATIC),
    ("quadratic_shepard", {"wall_extrapolation": "quadratic", "density_filter": "shepard"},
     ", quadratic walls, Shepard filter", CHANNEL_LIMITS_SHEPARD))


def channel_run_name(case, n, numerics="linear"):
    """The channel case's run of `case` at L/n with those numerics (CHANNEL_NUMERICS)."""
    return f"{case}_L{n}" + ("" if numerics == "linear" else f"_{numerics}")


def channel_numerics_of(nml):
    """The CHANNEL_NUMERICS name whose settings a resolved input has (None: none)."""
    numerics = nml["numerics"]
    chosen = {key: str(numerics.get(key, default)).strip().lower() for key, default in
              (("wall_extrapolation", "linear"), ("density_filter", "none"))}
    for name, settings, _, _ in CHANNEL_NUMERICS:
        wanted = {"wall_extrapolation": "linear", "density_filter": "none", **settings}
        if chosen == wanted:
            return name
    return None


def case_channel(runner, args):
    """Couette and Poiseuille from rest at L/20, L/40, L/80 and 3D Poiseuille at L/40, with
    Morris' wall extrapolation (as shipped), the quadratic one, and the quadratic one with
    the Shepard density filter: the README's accuracy table (linear) with the profile
    figures, and the other numerics' table in validation.md."""
    block = Block("channel")
    variants = Block("channel_numerics")
    rows = []
    figure_runs = {}
    for numerics, settings, _, _ in CHANNEL_NUMERICS:
        for case, source, resolutions in (("poiseuille", "poiseuille.nml", (20, 40, 80)),
                                          ("couette", "couette.nml", (20, 40, 80)),
                                          ("poiseuille_3d", "poiseuille_3d.nml", (40,))):
            for n in resolutions:
                out = runner.run(channel_run_name(case, n, numerics), source, {
                    "run": {"t_end": 2.0},
                    "domain": {"dx": 1.0e-3 / n},
                    "numerics": settings,
                    "output": {"output_interval": 0.0, "output_times": list(CHANNEL_TIMES)}})
                if out is None:
                    rows.append((case, n, numerics, None))
                    continue
                analytic = "couette" if case == "couette" else "poiseuille"
                errors = []
                for k, snap in enumerate(snapshots_at(out, CHANNEL_TIMES)):
                    steady = k == len(CHANNEL_TIMES) - 1
                    errors.append(l2_percent(snap, analytic, steady=steady))
                rows.append((case, n, numerics, errors))
                if n == 40 and case != "poiseuille_3d" and numerics == "linear":
                    figure_runs[case] = snapshots_at(out, CHANNEL_TIMES[:3])
    for table in (block, variants):
        table.lines += [
            "| case | t = 0.0225 s | 0.225 s | 1 s | steady (2 s) | limits | held |",
            "|---|---|---|---|---|---|---|"]
    titles = {"poiseuille": "Poiseuille", "couette": "Couette",
              "poiseuille_3d": "3D Poiseuille"}
    suffixes = {name: (suffix, limits) for name, _, suffix, limits in CHANNEL_NUMERICS}
    for case, n, numerics, errors in rows:
        suffix, all_limits = suffixes[numerics]
        limits = all_limits[(case, n)]
        table = block if numerics == "linear" else variants
        title = f"{titles[case]}, dx = L/{n}{suffix}"
        label = channel_run_name(case, n, numerics)
        if errors is None:
            table.failed.append(f"channel: {label} did not run")
            table.lines.append(f"| {title} | run failed | | | | | **NO** |")
            continue
        held = [table.check(f"{label} at {t} s", e, lim)
                for t, e, lim in zip(CHANNEL_TIMES, errors, limits)]
        ok = "yes" if all(h == "yes" for h in held) else "**NO**"
        cells = " | ".join(percent(e) for e in errors)
        table.lines.append(f"| {title} | {cells} | "
                           f"{' / '.join(f'{x:g}' for x in limits)} % | {ok} |")
    for case, files in figure_runs.items():
        figure = os.path.join(ROOT, "doc", f"{case}_profiles.png")
        status, text = script("sph_plot_profiles.py", *files, "--output", figure)
        if status != 0:
            block.failed.append(f"channel: the {case} figure failed: {text.strip()}")
    return [block, variants, channel_convergence(rows)]


def channel_convergence(rows, figure_dir=os.path.join(ROOT, "doc")):
    """The channel_convergence block: the 2D channels' errors at L/20, L/40, L/80 with the
    observed orders log2(e(n) / e(2n)) at each time, for Morris' walls and the quadratic
    ones, and channel_convergence.png in figure_dir. Reported, not held: the errors are held in the
    tables above."""
    block = Block("channel_convergence")
    errors = {(case, n, numerics): e for case, n, numerics, e in rows if e is not None}
    titles = {"poiseuille": "Poiseuille", "couette": "Couette"}
    walls = {"linear": "Morris' (linear)", "quadratic": "quadratic"}
    resolutions = (20, 40, 80)
    block.lines += ["| case | walls | t [s] | L/20 | L/40 | L/80 | order 20-40 | order 40-80 |",
                    "|---|---|---|---|---|---|---|---|"]
    curves = []
    for case in titles:
        for numerics in walls:
            found = [errors.get((case, n, numerics)) for n in resolutions]
            if any(e is None for e in found):
                block.failed.append(f"channel_convergence: {case} ({numerics}) lacks a run")
                continue
            for k, t in enumerate(CHANNEL_TIMES):
                e = [found[j][k] for j in range(3)]
                orders = [np.log2(e[j] / e[j + 1]) if e[j + 1] > 0 else float("nan")
                          for j in range(2)]
                block.lines.append(
                    f"| {titles[case]} | {walls[numerics]} | {t:g} | " +
                    " | ".join(percent(x) for x in e) + " | " +
                    " | ".join(f"{o:.2f}" for o in orders) + " |")
                curves.append((case, numerics, t, e))
    plt = pyplot(block)
    if plt is None:
        return block
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 4))
    for ax, case in zip(axes, titles):
        for case_, numerics, t, e in curves:
            if case_ != case:
                continue
            k = CHANNEL_TIMES.index(t)
            ax.loglog(resolutions, e, "o-" if numerics == "linear" else "s--", ms=4,
                      color=f"C{k}", label=f"t = {t:g} s, {walls[numerics]} walls")
        first = [e for case_, numerics, t, e in curves
                 if case_ == case and numerics == "linear" and t == CHANNEL_TIMES[0]]
        if first:
            guide = first[0][0] * (np.array(resolutions) / resolutions[0]) ** -2.0
            ax.loglog(resolutions, guide, "k:", lw=0.8, label="second order")
        ax.xaxis.set_minor_locator(plt.matplotlib.ticker.NullLocator())
        ax.set_xticks(resolutions)
        ax.set_xticklabels([f"L/{n}" for n in resolutions])
        ax.set_xlabel("particle spacing")
        ax.set_ylabel("relative L2 velocity error [%]")
        ax.set_title(titles[case], fontsize=10)
    # one legend beside both panels (the curves are the same in each)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center right", fontsize=8)
    fig.tight_layout(rect=(0.0, 0.0, 0.79, 1.0))
    fig.savefig(os.path.join(figure_dir, "channel_convergence.png"), dpi=120)
    plt.close(fig)
    block.lines += ["", "![errors of the channels against the spacing](channel_convergence.png)"]
    return block


def case_long_poiseuille(runner, args):
    """input/poiseuille_long.nml to 10 s with particle shifting (as shipped), without it, and
    without it but with same-level remeshing every second: the error against the steady
    profile over time (issue 9's long run; issue 10's long runs)."""
    block = Block("long_poiseuille")
    times = [float(t) for t in range(1, 11)]
    variants = (("shifting (as shipped)", "poiseuille_long", {}),
                ("no shifting", "poiseuille_long_plain",
                 {"numerics": {"shifting": "none"}}),
                ("same-level remeshing every 1 s, no shifting", "poiseuille_long_remesh",
                 {"numerics": {"shifting": "none"},
                  "remesh": {"mode": "same", "every_time": 1.0}}))
    curves = []
    block.lines += ["| t [s] | " + " | ".join(f"{t:g}" for t in times) + " | largest 2-10 s |",
                    "|---|" + "---|" * (len(times) + 1)]
    for label, name, overrides in variants:
        out = runner.run(name, "poiseuille_long.nml", overrides)
        if out is None:
            block.failed.append(f"long_poiseuille: the run '{label}' failed")
            continue
        errors = [l2_percent(s, "poiseuille", steady=True) for s in snapshots_at(out, times)]
        curves.append((label, errors))
        block.lines.append(f"| {label} | " + " | ".join(percent(e) for e in errors) +
                           f" | {percent(max(errors[1:]))} |")
    if curves:
        worst = max(curves[0][1][1:])
        # issue 9's target is the limit: the quintic spline meets it (physics.md)
        held = block.check("largest steady error 2-10 s (shifting)", worst, 0.3)
        best = min(curves, key=lambda c: max(c[1][1:]))
        block.lines += [
            "", f"Shipped input, largest from 2 to 10 s: {percent(worst)} (limit: issue 9's "
            f"0.3 %, held: {held}). Smallest largest error over 2-10 s: {best[0]}."]
    plt = pyplot(block)
    if plt is not None:
        fig, ax = plt.subplots(figsize=(6.5, 3.8))
        for label, errors in curves:
            ax.plot(times, errors, "o-", label=label)
        ax.axhline(0.3, color="gray", ls="--", label="issue 9 target 0.3 %")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("relative L2 error vs steady [%]")
        ax.set_title("Poiseuille, L/40, to 10 s")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(os.path.join(ROOT, "doc", "poiseuille_long_error.png"), dpi=150)
        plt.close(fig)
        block.lines += ["", "![error over time](poiseuille_long_error.png)"]
    return [block]


def cavity_scores(runner, block, name, source, figure, case, overrides=None):
    """Run (or reuse) a cavity and score it against Ghia: (RMS, largest) in % of U, or None
    (the reason added to the block)."""
    out = runner.run(name, source, overrides or {})
    if out is None:
        block.failed.append(f"{name}: the run failed")
        return None
    status, text = script("cavity_ghia.py", out, "--case", case, "--figure",
                          os.path.join(ROOT, "doc", figure))
    match = re.search(r"RMS error ([0-9.eE+-]+) % of U, largest ([0-9.eE+-]+) % of U", text)
    if status != 0 or match is None:
        block.failed.append(f"{name}: cavity_ghia failed: {text.strip()[-300:]}")
        return None
    return float(match.group(1)), float(match.group(2))


def cavity_block(runner, name, source, rms_limit, largest_limit, figure, case,
                 limit_source="the figures this page claims"):
    """The cavity's centre-line errors held to this page's limits, with issue 9's target
    (RMS 0.7 %, largest 1.5 % of U) reported beside them, met or not."""
    block = Block(name)
    scores = cavity_scores(runner, block, name, source, figure, case)
    if scores is None:
        return block
    rms, largest = scores
    block.lines += [
        "| | RMS error | largest error |",
        "|---|---|---|",
        f"| `input/{source}` | {rms:.2f} % of U | {largest:.2f} % of U |",
        f"| limit: {limit_source} (held) | {rms_limit} % "
        f"({block.check('RMS', rms, rms_limit)}) | "
        f"{largest_limit} % ({block.check('largest', largest, largest_limit)}) |",
        f"| issue 9's target | 0.7 % ({'met' if rms <= 0.7 else 'not met'}) | "
        f"1.5 % ({'met' if largest <= 1.5 else 'not met'}) |",
        "", f"![cavity against Ghia]({figure})"]
    return block


def case_cavity(runner, args):
    """The Re = 100 lid-driven cavity with the transport velocity against Ghia et al.
    (1982): held to the spread of realisations that differ by round-off (RMS 0.35-0.81 %,
    largest 1.11-2.17 % of U over eight runs, validation.md), issue 9's target (RMS 0.7,
    largest 1.5 %; PySPH's TVF scores 0.74 / 1.50 %) reported beside it."""
    return [cavity_block(runner, "cavity", "cavity_tvf.nml", 0.9, 2.5, "cavity_re100_ghia.png",
                         "cavity_tvf", "the round-off realisations' spread, with a margin")]


def case_cavity_fine(runner, args):
    """The Re = 100 transport-velocity cavity at L/100 against L/50: issue 9 asks for
    smaller errors at the finer resolution (both within 0.7 / 1.5 % of U)."""
    block = Block("cavity_fine")
    coarse = cavity_scores(runner, block, "cavity", "cavity_tvf.nml", "cavity_re100_ghia.png",
                           "cavity_tvf")
    fine = cavity_scores(runner, block, "cavity_L100", "cavity_tvf.nml",
                         "cavity_re100_L100_ghia.png", "cavity_tvf",
                         {"domain": {"dx": 1.0e-5}})
    if coarse is None or fine is None:
        return [block]
    block.lines += [
        "| resolution | RMS error | largest error |",
        "|---|---|---|",
        f"| L/50 | {coarse[0]:.2f} % of U | {coarse[1]:.2f} % of U |",
        f"| L/100 | {fine[0]:.2f} % of U | {fine[1]:.2f} % of U |",
        f"| L/100 within 0.7 / 1.5 % | {block.check('L/100 RMS', fine[0], 0.7)} | "
        f"{block.check('L/100 largest', fine[1], 1.5)} |",
        f"| L/100 below L/50 | {block.check('L/100 RMS above L/50', fine[0], coarse[0])} | "
        f"{block.check('L/100 largest above L/50', fine[1], coarse[1])} |",
        "", "![cavity at L/100 against Ghia](cavity_re100_L100_ghia.png)"]
    return [block]


def case_cavity_wcsph(runner, args):
    """The same cavity without the transport velocity (background pressure and shifting)."""
    return [cavity_block(runner, "cavity_wcsph", "cavity.nml", 4.0, 7.5,
                         "cavity_re100_wcsph_ghia.png", "cavity")]


def case_cavity_re1000(runner, args):
    """The Re = 1000 cavity: runs to steady state without blowing up (long)."""
    return [cavity_block(runner, "cavity_re1000", "cavity_re1000.nml", 30.0, 50.0,
                         "cavity_re1000_ghia.png", "cavity_re1000")]


def body_lattice_block(runner, name, body, resolutions, parallel_from, source=None,
                       overrides=None, reference_limit=None, converge=True):
    """Runs of input/<source or name>.nml (with `overrides`) at the resolutions L/n (1 rank
    below n = parallel_from): the drag on `body` balances the body force within 1 % and,
    with three resolutions, converges (unless not converge); with reference_limit the mean
    fluid velocity lies within that many percent of Sangani & Acrivos' (body_drag.py)."""
    block = Block(name)
    outs = []
    for n in resolutions:
        values = {group: dict(keys) for group, keys in (overrides or {}).items()}
        values.setdefault("domain", {})["dx"] = 0.1 / n
        serial = n < parallel_from
        out = runner.run(f"{name}_L{n}" + ("_np1" if serial else ""), source or f"{name}.nml",
                         values, nranks=1 if serial else None)
        if out is None:
            block.failed.append(f"{name}: L/{n} failed")
            return [block]
        outs.append(out)
    case = (source or f"{name}.nml").rsplit(".", 1)[0]
    # step means (Fx_mean), weighted by the time each row covers: the instantaneous rows carry
    # the particles' noise (a few per cent around a cylinder)
    flags = ["--case", case, "--body", body, "--fraction", "0.5", "--max-imbalance", "1.0",
             "--time-averaged"]
    if reference_limit is not None:
        flags += ["--max-reference-deviation", str(reference_limit)]
    converge = converge and len(outs) >= 3
    if converge:
        flags.append("--require-convergence")
    figure = f"{name}_drag.png"
    flags += ["--figure", os.path.join(ROOT, "doc", figure)]
    status, text = script("body_drag.py", *outs, *flags)
    text = runner.relative(text)
    reference = ("" if reference_limit is None else
                 f", mean velocity within {reference_limit:g} % of Sangani & Acrivos")
    block.lines += ["```", text.strip(), "```", "",
                    f"Drag within 1 % of the body force"
                    f"{' and converging' if converge else ''}{reference}: "
                    f"{'yes' if status == 0 else '**NO**'}", "",
                    f"![{name}: drag and mean fluid velocity over time]({figure})"]
    if status != 0:
        block.failed.append(f"{name}: body_drag reported a threshold exceeded")
    return [block]


def case_cylinder(runner, args):
    """Morris' cylinder lattice at L/25, L/50 (and L/100 unless --skip-long): the drag
    balances the body force within 1 % and converges with resolution."""
    return body_lattice_block(runner, "cylinder", "cylinder",
                              (25, 50) if args.skip_long else (25, 50, 100), 100)


def case_cylinder_stokes(runner, args):
    """Morris' cylinder lattice in the Stokes regime (nu = 1e-5, Re about 0.01) at L/25 and
    L/50 (and L/100 unless --skip-long): the mean fluid velocity within 1.5 % of Sangani &
    Acrivos' expansion for a square array at every resolution, the drag within 1 % of the
    body force. Not held to converge: its changes are at the level of the time averages'
    noise (0.1 %)."""
    stokes = {"fluid": {"nu": 1.0e-5, "velocity_scale": 6.0e-6},
              "run": {"t_end": 1500.0}, "output": {"output_interval": 100.0}}
    return body_lattice_block(runner, "cylinder_stokes", "cylinder",
                              (25, 50) if args.skip_long else (25, 50, 100), 100,
                              source="cylinder.nml", overrides=stokes, reference_limit=1.5,
                              converge=False)


def case_sphere(runner, args):
    """The 3D sphere lattice at L/20, L/30 (and L/40 unless --skip-long): the drag balances
    the body force within 1 % and converges with resolution; the mean fluid velocity against
    Sangani & Acrivos' simple cubic array."""
    return body_lattice_block(runner, "sphere", "sphere",
                              (20, 30) if args.skip_long else (20, 30, 40), 40)


def grid_velocity(snapshot, points, dx):
    """Gaussian-weighted mean fluid velocity (weight exp(-d^2/dx^2), particles within 3 dx,
    periodic box) at each point; NaN where no particle is in reach."""
    snap = sph_snapshot.load(snapshot)
    geo = sph_snapshot.geometry(snap)
    lo, hi = np.asarray(geo["box_lo"])[:2], np.asarray(geo["box_hi"])[:2]
    fluid = snap["kind"] == 0
    x = snap["position"][fluid, :2]
    v = snap["velocity"][fluid, :2]
    size = hi - lo
    out = np.full((len(points), 2), np.nan)
    for k, p in enumerate(points):
        d = x - p
        d -= size * np.round(d / size)
        r2 = (d ** 2).sum(axis=1)
        near = r2 < (3.0 * dx) ** 2
        if near.any():
            w = np.exp(-r2[near] / dx ** 2)
            out[k] = (w[:, None] * v[near]).sum(axis=0) / w.sum()
    return out


def case_cylinder_remesh(runner, args):
    """Morris' cylinder at L/50 with same-level remeshing every 500 s (the shipped
    input/cylinder_remesh.nml) against the same flow without (input/cylinder.nml): the
    developed velocity field (relative L2 over the fluid of the mean over 3000-6000 s) and
    the drag within 2 % (issue 10)."""
    block = Block("cylinder_remesh")
    plain = runner.run("cylinder_L50_np1", "cylinder.nml", {"domain": {"dx": 2.0e-3}},
                       nranks=1)
    remeshed = runner.run("cylinder_L50_remesh", "cylinder_remesh.nml", {}, nranks=1)
    if plain is None or remeshed is None:
        block.failed.append("cylinder_remesh: a run failed")
        return [block]
    dx = 2.0e-3
    axis = np.arange(0.5, 50) * dx
    points = np.array([[a, b] for a in axis for b in axis
                       if np.hypot(a - 0.05, b - 0.05) > 0.02 + 2.0 * dx])
    # "once developed": the time-mean fields over 3000-6000 s (the snapshots every 250 s);
    # a single snapshot carries the particles' noise, which is measured too (the run
    # without remeshing against itself 250 s earlier)
    series = [[f for f in sph_snapshot.list_snapshots(o)
               if snapshot_time(f) >= 3000.0 - 1.0] for o in (plain, remeshed)]
    fields = [np.array([grid_velocity(f, points, dx) for f in fs]) for fs in series]

    def l2(a, b):
        ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
        return 100.0 * np.linalg.norm(a[ok] - b[ok]) / np.linalg.norm(b[ok]), int(ok.sum())

    diff, n_points = l2(fields[1].mean(axis=0), fields[0].mean(axis=0))
    last_diff, _ = l2(fields[1][-1], fields[0][-1])
    noise, _ = l2(fields[0][-2], fields[0][-1])
    status, text = script("body_drag.py", plain, remeshed, "--case", "cylinder",
                          "--fraction", "0.5", "--time-averaged", "--labels",
                          "L/50,L/50 remeshed every 500 s", "--figure",
                          os.path.join(ROOT, "doc", "cylinder_remesh_drag.png"))
    drawn = "body_drag: wrote" in text
    text = runner.relative(text)
    drags = [float(v) for v in re.findall(r", drag ([0-9.eE+-]+),", text)][:2]
    drag_diff = (100.0 * abs(drags[1] - drags[0]) / abs(drags[0])
                 if len(drags) == 2 else None)
    block.lines += [
        "| | value | limit | held |", "|---|---|---|---|",
        f"| velocity, relative L2 difference of the mean fields over 3000-6000 s "
        f"({len(series[0])} and {len(series[1])} snapshots, {n_points} points) | "
        f"{diff:.2f} % | 2 % | {block.check('velocity difference', diff, 2.0)} |",
        f"| the same at 6000 s alone (not a limit) | {last_diff:.2f} % | | |",
        f"| without remeshing, 5750 s against 6000 s: the particle noise (not a limit) | "
        f"{noise:.2f} % | | |",
        f"| drag (mean over 3000-6000 s), relative difference | {percent(drag_diff)} | 2 % | "
        f"{block.check('drag difference', drag_diff, 2.0)} |",
        "", "```", text.strip(), "```", "",
        "![cylinder with and without remeshing: drag and mean fluid velocity over time]"
        "(cylinder_remesh_drag.png)"]
    if status != 0 or not drawn:
        block.failed.append(f"cylinder_remesh: body_drag failed: {text.strip()[-300:]}")
    return [block]


def window_drags(out, case, windows):
    """Mean drag (x) per time window from <case>_forces.csv: the rows' step means (Fx_mean),
    weighted by the time each row covers."""
    import csv
    with open(os.path.join(out, f"{case}_forces.csv")) as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["time"]) for r in rows])
    fx = np.array([float(r["Fx_mean"]) for r in rows])
    start = np.concatenate([[0.0], t[:-1]])
    means = []
    for lo, hi in windows:
        inside = (start >= lo - 1.0) & (t <= hi + 1.0)
        means.append((fx[inside] * (t - start)[inside]).sum() / (t - start)[inside].sum())
    return means


def case_cylinder_multires(runner, args):
    """Morris' cylinder with L/50 particles within 12 mm of its surface and L/25 further out
    (input/cylinder_multires.nml) against the uniformly fine L/50 run: the drag per window
    within 2 % once developed (from 3000 s) and the real fluid mass within 0.1 % (issue 11)."""
    block = Block("cylinder_multires")
    plain = runner.run("cylinder_L50_np1", "cylinder.nml", {"domain": {"dx": 2.0e-3}},
                       nranks=1)
    multi = runner.run("cylinder_multires", "cylinder_multires.nml", {})
    if plain is None or multi is None:
        block.failed.append("cylinder_multires: a run failed")
        return [block]
    windows = ((1500.0, 3000.0), (3000.0, 4500.0), (4500.0, 6000.0), (3000.0, 6000.0))
    uniform = window_drags(plain, "cylinder", windows)
    multires = window_drags(multi, "cylinder_multires", windows)
    block.lines += ["| window [s] | drag, L/50 [N/m] | drag, L/25 + L/50 ring [N/m] | "
                    "difference | limit | held |", "|---|---|---|---|---|---|"]
    for (lo, hi), a, b in zip(windows, uniform, multires):
        diff = 100.0 * (b - a) / a
        developed = lo >= 3000.0
        held = block.check(f"drag {lo:.0f}-{hi:.0f} s", abs(diff), 2.0) if developed else ""
        block.lines.append(f"| {lo:.0f}-{hi:.0f} | {a:.4e} | {b:.4e} | {diff:+.2f} % | "
                           f"{'2 %' if developed else '(developing)'} | {held} |")
    with open(os.path.join(runner.work, "cylinder_multires.log")) as f:
        drifts = [float(v) for v in re.findall(
            r"all levels: real mass +[0-9.eE+-]+ kg \(drift +([0-9.eE+-]+)\)", f.read())]
    worst = 100.0 * max(abs(d) for d in drifts) if drifts else None
    block.lines += ["", f"Real fluid mass: largest drift over the run's {len(drifts)} log "
                    f"lines {worst:.2g} % (limit 0.1 %): "
                    f"{block.check('real mass drift', worst, 0.1)}"]
    # each folder's case from its one forces file (cylinder, cylinder_multires)
    status, text = script("body_drag.py", plain, multi, "--fraction", "0.5", "--time-averaged",
                          "--labels", "L/50,L/25 with an L/50 ring", "--figure",
                          os.path.join(ROOT, "doc", "cylinder_multires_drag.png"))
    if status != 0:
        block.failed.append(f"cylinder_multires: body_drag failed: {text.strip()[-300:]}")
    block.lines += ["", "![cylinder with a refined ring against the uniformly fine run: drag and "
                    "mean fluid velocity over time](cylinder_multires_drag.png)"]
    return [block]


def remesh_offline(runner, mode, source, target):
    """`sphremesh --remesh mode source target` on the runner's ranks (its log beside target);
    True when it worked."""
    # the remesh never replaces a file: this folder's result of a run before goes
    if os.path.exists(target):
        os.remove(target)
    cmd = ["mpirun", "-np", str(runner.nranks), runner.binary, "--remesh", mode, source, target]
    with open(target + ".log", "w") as log:
        status = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
    runner.note_version(target + ".log")
    return status == 0


def disorder_checks(mode, before, after, new_dx):
    """Issue 10's "disorder kept" checks of one offline remesh to spacing new_dx: (label,
    value, held) for the count, the mean nearest distance, the minimum pair and the CoV of the
    nearest distances."""
    import sph_disorder
    dim = before["dimension"]
    factor = 2 ** dim if mode == "refine" else 1.0 / 2 ** dim
    count_tol = 0.02 if mode == "refine" else 0.05
    mean_target = 0.5 if mode == "refine" else 2.0
    r = sph_disorder.ratios(before, after)
    cov_ok = (after["cov_nn"] <= 0.05 if before["cov_nn"] < 0.02
              else abs(r["cov_nn"] - 1.0) <= 0.25)
    return [
        ("count ratio", f"{r['count']:.4g}", abs(r["count"] / factor - 1.0) <= count_tol),
        ("mean ratio", f"{r['mean_nn']:.4g}", abs(r["mean_nn"] / mean_target - 1.0) <= 0.05),
        ("min pair / new spacing", f"{after['min_pair'] / new_dx:.3g}",
         after["min_pair"] >= 0.4 * new_dx),
        ("CoV", f"{before['cov_nn']:.3f} -> {after['cov_nn']:.3f}", cov_ok)]


def case_remesh_disorder(runner, args):
    """Issue 10's "disorder kept": offline refine and coarsen of the developed Poiseuille flow
    (L/40 at 2 s) and of the cylinder flow (L/25, L/50 at 0, 1500 and 6000 s), the count,
    mean spacing, minimum pair and CoV checks."""
    import sph_disorder
    block = Block("remesh_disorder")
    sources = [("Poiseuille L/40", runner.run("poiseuille_L40", "poiseuille.nml", {
                   "run": {"t_end": 2.0}, "domain": {"dx": 1.0e-3 / 40},
                   "output": {"output_interval": 0.0, "output_times": list(CHANNEL_TIMES)}}),
                (2.0,)),
               ("cylinder L/25", runner.run("cylinder_L25", "cylinder.nml",
                                            {"domain": {"dx": 0.1 / 25}}), (0.0, 1500.0, 6000.0)),
               ("cylinder L/50", runner.run("cylinder_L50", "cylinder.nml",
                                            {"domain": {"dx": 0.1 / 50}}), (0.0, 1500.0, 6000.0))]
    block.lines += ["| flow | t [s] | remesh | particles | count ratio | mean ratio | "
                    "min pair / new spacing | CoV before -> after |",
                    "|---|---|---|---|---|---|---|---|"]
    scratch = os.path.join(runner.work, "remesh_disorder")
    os.makedirs(scratch, exist_ok=True)
    histograms = {}     # (flow, last time): the figure's nearest distances
    for label, out, times in sources:
        if out is None:
            block.failed.append(f"remesh_disorder: the {label} run failed")
            continue
        for snap, t in zip(snapshots_at(out, times), times):
            before = sph_disorder.disorder(snap)
            for mode in ("refine", "coarsen"):
                target = os.path.join(scratch, f"{label.replace(' ', '_').replace('/', '')}"
                                               f"_{t:g}_{mode}.h5")
                if not remesh_offline(runner, mode, snap, target):
                    block.failed.append(f"remesh_disorder: {label} {t:g} s {mode} failed")
                    continue
                after = sph_disorder.disorder(target)
                dx = sph_snapshot.geometry(sph_snapshot.load(snap))["dx"]
                checks = disorder_checks(mode, before, after,
                                         dx * (0.5 if mode == "refine" else 2.0))
                # issue 10 asks it of developed flows; the initial lattices are reported
                developed = t > 0.0
                for what, value, held in checks:
                    if not held and developed:
                        block.failed.append(f"remesh_disorder: {label} at {t:g} s, {mode}: "
                                            f"{what} {value} outside issue 10's limit")
                if t == times[-1] and developed:
                    drawn = histograms.setdefault((label, t), {
                        "dx": dx, "nearest": before["nearest"], "remeshed": []})
                    drawn["remeshed"].append(
                        (mode, dx * (0.5 if mode == "refine" else 2.0), after["nearest"]))
                mark = " **NO**" if developed else " (outside)"
                cells = [f"{value}" + ("" if held else mark) for _, value, held in checks]
                when = f"{t:g}" if developed else f"{t:g} (initial lattice)"
                block.lines.append(f"| {label} | {when} | {mode} | {before['count']} -> "
                                   f"{after['count']} | " + " | ".join(cells) + " |")
    disorder_figure(block, histograms)
    block.lines += ["", "Limits (issue 10): refine 2^dim N within 2 %, mean nearest distance "
                    "half the original's within 5 %; coarsen N/2^dim within 5 %, mean twice "
                    "within 5 %; both: no pair closer than 0.4 new spacings, CoV within 25 % "
                    "of the original's (at most 0.05 where the original's is below 0.02), "
                    "held for the developed flows (t > 0). **NO** marks a limit missed; "
                    "(outside) marks an initial lattice's figure outside it (reported, not "
                    "held)."]
    return [block]


def disorder_figure(block, histograms, figure_dir=os.path.join(ROOT, "doc")):
    """remesh_disorder.png in figure_dir: for each developed flow, the distribution of the
    fluid particles' nearest distances over their spacing before the remesh and after its
    refinement and coarsening ({(label, t): {"dx", "nearest", "remeshed": [(mode, new dx,
    nearest)]}})."""
    if not histograms:
        return
    plt = pyplot(block)
    if plt is None:
        return
    fig, axes = plt.subplots(1, len(histograms), figsize=(4.2 * len(histograms), 3.6),
                             squeeze=False)
    bins = np.linspace(0.0, 1.6, 65)
    for ax, ((label, t), drawn) in zip(axes[0], histograms.items()):
        dx, nearest, remeshed = drawn["dx"], drawn["nearest"], drawn["remeshed"]
        ax.hist(nearest / dx, bins=bins, density=True, histtype="stepfilled", color="0.8",
                label=f"flow, N = {len(nearest)}")
        for mode, new_dx, after in remeshed:
            ax.hist(after / new_dx, bins=bins, density=True, histtype="step", lw=1.2,
                    label=f"{ {'refine': 'refined', 'coarsen': 'coarsened'}[mode]}, "
                          f"N = {len(after)}")
        ax.axvline(0.4, color="r", ls=":", lw=0.8, label="closest allowed (0.4)")
        ax.set_title(f"{label} at {t:g} s", fontsize=9)
        ax.set_xlabel("nearest distance / own spacing")
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("probability density")
    fig.tight_layout()
    fig.savefig(os.path.join(figure_dir, "remesh_disorder.png"), dpi=120)
    plt.close(fig)
    block.lines += ["", "![nearest distances before and after remeshing the developed flows]"
                    "(remesh_disorder.png)"]


def case_remesh_continue(runner, args):
    """Developed flows remeshed offline and continued at the new spacing, against the run made
    at that spacing throughout: Poiseuille refined from L/20 at 0.5 s and continued at L/40
    to 1 s (issue 10: error within 1.25x of the L/40 run's), coarsened from L/40 at 0.5 s and
    continued at L/20 (held to the same 1.25x: no issue asks it, it guards the coarsening's
    wall rows); Morris' cylinder refined from L/25 and coarsened from L/50 at 1500 s
    and continued to 6000 s (drag and mean fluid velocity over 3000-6000 s, reported)."""
    import body_drag
    block = Block("remesh_continue")
    scratch = os.path.join(runner.work, "remesh_continue")
    os.makedirs(scratch, exist_ok=True)
    block.lines += ["| flow | measure | remeshed and continued | run at the new spacing "
                    "throughout | ratio or difference | limit | held |",
                    "|---|---|---|---|---|---|---|"]

    def continued(label, mode, source_run, time, name, nml, dx, checkpoint=False):
        """source_run's state at `time` (its last checkpoint if asked) remeshed and run on
        from there as `name` with input/nml at spacing dx; its output folder or None."""
        if source_run is None:
            return None
        if checkpoint:
            found = sorted(glob.glob(os.path.join(source_run, "*_checkpoint_*.h5")))
            source = found[-1] if found else None
        else:
            source = snapshots_at(source_run, (time,))[0]
        target = os.path.join(scratch, f"{name}.h5")
        if source is None or not remesh_offline(runner, mode, source, target):
            block.failed.append(f"remesh_continue: {label}: the {mode} failed")
            return None
        return runner.run(name, nml, {"domain": {"dx": dx}}, restart=target)

    # Poiseuille: issue 10's recipe and its reverse
    l20_half = runner.run("poiseuille_L20_half", "poiseuille_refine_coarse.nml", {})
    l40_half = runner.run("poiseuille_L40_half", "poiseuille_refine_coarse.nml",
                          {"domain": {"dx": 1.0e-3 / 40}})
    l40 = runner.run("poiseuille_L40_to1", "poiseuille_refine.nml", {})
    l20 = runner.run("poiseuille_L20_to1", "poiseuille_refine_coarse.nml",
                     {"run": {"t_end": 1.0}})
    for label, mode, source, plain, name, dx, limit in (
            ("Poiseuille L/20 at 0.5 s -> L/40", "refine", l20_half, l40,
             "poiseuille_L20_refined_L40", 1.0e-3 / 40, 1.25),
            ("Poiseuille L/40 at 0.5 s -> L/20", "coarsen", l40_half, l20,
             "poiseuille_L40_coarsened_L20", 1.0e-3 / 20, 1.25)):
        cont = continued(label, mode, source, 0.5, name, "poiseuille_refine.nml", dx,
                         checkpoint=True)
        if cont is None or plain is None:
            block.failed.append(f"remesh_continue: {label}: a run failed")
            continue
        a = l2_percent(snapshots_at(cont, (1.0,))[0], "poiseuille")
        b = l2_percent(snapshots_at(plain, (1.0,))[0], "poiseuille")
        held = block.check(f"{label}: error ratio", a / b, limit, unit="x") if limit else ""
        block.lines.append(f"| {label} | relative L2 error at 1 s | {percent(a)} | "
                           f"{percent(b)} | {a / b:.2f}x | "
                           f"{f'{limit}x' if limit else '(reported)'} | {held} |")
    # the cylinder both ways
    l25 = runner.run("cylinder_L25", "cylinder.nml", {"domain": {"dx": 0.1 / 25}})
    l50 = runner.run("cylinder_L50", "cylinder.nml", {"domain": {"dx": 0.1 / 50}})
    drawn = []
    for label, mode, source, plain, name, dx in (
            ("cylinder L/25 at 1500 s -> L/50", "refine", l25, l50,
             "cylinder_L25_refined_L50", 0.1 / 50),
            ("cylinder L/50 at 1500 s -> L/25", "coarsen", l50, l25,
             "cylinder_L50_coarsened_L25", 0.1 / 25)):
        cont = continued(label, mode, source, 1500.0, name, "cylinder.nml", dx)
        if cont is None or plain is None:
            block.failed.append(f"remesh_continue: {label}: a run failed")
            continue
        window = ((3000.0, 6000.0),)
        drag = (window_drags(cont, "cylinder", window)[0],
                window_drags(plain, "cylinder", window)[0])
        speed = tuple(body_drag.mean_speed(body_drag.speed_series(
            body_drag.snapshots(out, "cylinder"), 0), 3000.0) for out in (cont, plain))
        for what, (a, b), unit in (("drag, mean 3000-6000 s", drag, "N/m"),
                                   ("mean fluid velocity, 3000-6000 s", speed, "m/s")):
            block.lines.append(f"| {label} | {what} [{unit}] | {a:.4e} | {b:.4e} | "
                               f"{100.0 * (a - b) / b:+.2f} % | (reported) | |")
        new_n = round(0.1 / dx)
        drawn += [(cont, f"{label} (continued)"), (plain, f"L/{new_n} throughout")]
    if drawn:
        figure = "remesh_continue_cylinder.png"
        status, text = script("body_drag.py", *[out for out, _ in drawn], "--case", "cylinder",
                              "--time-averaged", "--labels", ",".join(l for _, l in drawn),
                              "--figure", os.path.join(ROOT, "doc", figure))
        if status != 0:
            block.failed.append(f"remesh_continue: body_drag failed: {text.strip()[-300:]}")
        block.lines += ["", "![the cylinder remeshed at 1500 s and continued, against the runs "
                        f"at the new spacing throughout]({figure})"]
    return [block]


def case_multires(runner, args):
    """Multi-resolution Couette and Poiseuille (L/20 channel, L/40 band or lower half): error
    per level against the uniform runs (same numerics) in the same region, their
    ratio (issue 11: at most 1.25, reported, not held), and the density jump at the
    interfaces."""
    block = Block("multires")
    block.lines += ["| case | level | t = 0.0225 s | 0.225 s | 1 s | uniform there "
                    "(0.0225 / 0.225 / 1 s) | ratio | interface jump [% rho0] |",
                    "|---|---|---|---|---|---|---|---|"]
    worst_ratio = {0: 0.0, 1: 0.0}
    times = CHANNEL_TIMES[:3]
    # (label, analytic case, input, extra namelist settings, run name, profile figure)
    subcycled = {"numerics": {"integrator": "verlet"}, "refinement": {"max_subcycles": 4}}
    variants = (("poiseuille", "poiseuille", "poiseuille_multires.nml", {},
                 "poiseuille_multires", True),
                ("poiseuille, fine lower half", "poiseuille", "poiseuille_multires_wall.nml", {},
                 "poiseuille_multires_wall", False),
                # with the filter the steady error is 0.009 %, and the net push left in
                # (remove_push = .false., as the input has it) doubled it
                ("poiseuille, Shepard filter, push removed", "poiseuille",
                 "poiseuille_multires.nml", {"numerics": {"density_filter": "shepard"},
                                             "refinement": {"remove_push": True}},
                 "poiseuille_multires_shepard", False),
                ("couette", "couette", "couette_multires.nml", {}, "couette_multires", True),
                ("poiseuille, Verlet, max_subcycles = 4", "poiseuille",
                 "poiseuille_multires.nml", subcycled, "poiseuille_multires_subcycled", False))
    for label, case, source, extra, name, figure in variants:
        out = runner.run(name, source, {
            "output": {"output_interval": 0.0, "output_times": list(times)}, **extra})
        if out is None:
            block.failed.append(f"multires: {label} failed")
            continue
        snaps = snapshots_at(out, times)
        nml = sph_snapshot.namelist(sph_snapshot.load(snaps[-1]))
        band = region_band(nml)
        # the uniform runs of the channel case with the same numerics (none: no reference)
        numerics = channel_numerics_of(nml)
        uniform = {n: os.path.join(runner.work, channel_run_name(case, n, numerics or "none"))
                   for n in (20, 40)}
        profile = (["--figure", os.path.join(ROOT, "doc", f"{case}_multires_profile.png")]
                   if figure else [])
        status, jumps = script("sph_interface_profile.py", snaps[-1], *profile)
        worst = max([abs(float(v)) for v in re.findall(
            r"^\s*[0-9.eE+-]+\s+[0-9.]+\s+[0-9.]+\s+(-?[0-9.eE+-]+)", jumps, re.M)] or [np.nan])
        jump_ok = block.check(f"{label} interface density jump", worst, 0.2)
        for level, n in ((0, 20), (1, 40)):
            errors = [l2_percent(s, case, level=level) for s in snaps]
            ref, ratio = "n/a", "n/a"
            if os.path.isdir(uniform[n]):
                # the fine level lies in the region's band, the coarse one outside it
                restrict = {"band": band} if level == 1 else {"outside": band}
                ref_errors = [l2_percent(s, case, **restrict)
                              for s in snapshots_at(uniform[n], times)]
                ratios = [e / r for e, r in zip(errors, ref_errors)]
                worst_ratio[level] = max([worst_ratio[level]] + ratios)
                ref = " / ".join(percent(e) for e in ref_errors)
                ratio = " / ".join(f"{x:.2f}" for x in ratios)
            block.lines.append(f"| {label} | {level} (L/{n}) | " +
                               " | ".join(percent(e) for e in errors) +
                               f" | {ref} | {ratio} | {worst:.4f} ({jump_ok}) |")
    # one table: a blank line between its rows would end it (the rows after it showed as text)
    block.lines += [
        "",
        "Largest ratio to the uniform run in the same region: coarse "
        f"{worst_ratio[0]:.2f}, fine {worst_ratio[1]:.2f}",
        "(issue 11's target: 1.25 at every time).", "",
        "![Poiseuille multires profile](poiseuille_multires_profile.png)"]
    return [block]


def region_band(nml):
    """(lo, hi) in y of the first &region box of a resolved input (f90nml Namelist)."""
    region = nml["region"]
    if isinstance(region, list):
        region = region[0]
    return float(region["lo"][1]), float(region["hi"][1])


def case_ranks(runner, args):
    """The Poiseuille channel for 1,000 steps on 1, 2 and 4 ranks: velocities by particle id
    agree within 1e-9 of the peak."""
    block = Block("ranks")
    velocities, last = {}, {}
    for n in (1, 2, 4):
        out = runner.run(f"ranks_np{n}", "poiseuille.nml", {
            "run": {"t_end": 0.132},
            "output": {"output_interval": 0.0, "output_times": [0.132]}}, nranks=n)
        if out is None:
            block.failed.append(f"ranks: the run on {n} ranks failed")
            return [block]
        snap = sph_snapshot.load(sph_snapshot.list_snapshots(out)[-1])
        order = np.argsort(snap["id"])
        velocities[n] = (snap["id"][order], snap["velocity"][order], snap["step"])
        fluid = snap["kind"][order] == 0
        last[n] = (snap, fluid, snap["position"][order])
    ids1, v1, steps = velocities[1]
    peak = np.abs(v1).max()
    block.lines += ["| ranks | steps | particles | largest difference / peak velocity | held |",
                    "|---|---|---|---|---|"]
    for n in (1, 2, 4):
        ids, v, s = velocities[n]
        same = len(ids) == len(ids1) and np.array_equal(ids, ids1)
        diff = np.abs(v - v1).max() / peak if same else np.inf
        ok = block.check(f"{n} ranks against 1", diff, 1.0e-9, unit="")
        block.lines.append(f"| {n} | {s} | {len(ids)} | {diff:.2e} | {ok} |")
    if all(len(velocities[n][0]) == len(ids1) and np.array_equal(velocities[n][0], ids1)
           for n in (2, 4)):
        rank_figure(block, velocities, last, peak)
    return [block]


def rank_figure(block, velocities, last, peak):
    """doc/rank_invariance.png: the fluid's velocity profiles of the runs on 1, 2 and 4 ranks
    against the transient analytic profile, and each particle's velocity difference from the
    1-rank run over the peak, against the limit."""
    plt = pyplot(block)
    if plt is None:
        return
    snap, fluid, pos = last[1]
    par = sph_error_table.channel_parameters(snap["attrs"].get("input", ""))
    y = sph_error_table.wall_distance(par, pos[fluid])
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    ys = np.linspace(0.0, par["width"], 200)
    left.plot(sph_analytic.channel(par["case"], ys, float(snap["time"]), par), ys * 1e3, "k-",
              lw=0.8, label=f"analytic, t = {float(snap['time']):g} s")
    # a floor for the log scale: a difference of exactly 0 is drawn there
    floor = 1e-18
    for n, marker in ((1, "o"), (2, "x"), (4, "+")):
        v = velocities[n][1][fluid, par["flow"]]
        left.plot(v, y * 1e3, marker, ms=3, ls="none", label=f"{n} rank{'s' if n > 1 else ''}")
        if n > 1:
            d = np.abs(velocities[n][1] - velocities[1][1])[fluid].max(axis=1) / peak
            right.semilogy(y * 1e3, np.maximum(d, floor), marker, ms=3, ls="none",
                           label=f"{n} ranks against 1")
    right.axhline(1e-9, color="r", ls="--", lw=0.8, label="limit 1e-9")
    right.set_ylim(floor / 2, 1e-7)
    left.set_xlabel("velocity along the flow [m/s]")
    left.set_ylabel("distance from the wall [mm]")
    right.set_xlabel("distance from the wall [mm]")
    right.set_ylabel("|v - v(1 rank)| / peak velocity")
    right.set_title(f"after {velocities[1][2]} steps (0 drawn at {floor:g})", fontsize=9)
    for ax in (left, right):
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(ROOT, "doc", "rank_invariance.png"), dpi=120)
    plt.close(fig)
    block.lines += ["", "![velocity profiles on 1, 2 and 4 ranks and their differences]"
                    "(rank_invariance.png)"]


# blocks in doc/validation.md besides those named as their case
EXTRA_BLOCKS = ("channel_numerics", "channel_convergence")

CASES = {
    "channel": (case_channel, False),
    "ranks": (case_ranks, False),
    "multires": (case_multires, False),
    "long_poiseuille": (case_long_poiseuille, False),
    "cavity": (case_cavity, False),
    "cavity_wcsph": (case_cavity_wcsph, False),
    "cavity_fine": (case_cavity_fine, True),
    "cylinder": (case_cylinder, False),
    "cylinder_stokes": (case_cylinder_stokes, False),
    "sphere": (case_sphere, False),
    "cylinder_remesh": (case_cylinder_remesh, False),
    "cylinder_multires": (case_cylinder_multires, False),
    "remesh_disorder": (case_remesh_disorder, False),
    "remesh_continue": (case_remesh_continue, False),
    "cavity_re1000": (case_cavity_re1000, True),
}


# ----------------------------------------------------------------------------- documents

def replace_block(path, name, lines, stamp):
    """Put `lines` between the markers of block `name` in `path`; False when absent."""
    with open(path) as f:
        text = f.read()
    begin, end = f"<!-- validate:{name} -->", f"<!-- /validate:{name} -->"
    if begin not in text or end not in text:
        return False
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    body = "\n".join([begin, f"<!-- generated by scripts/validate, {stamp} -->"] + lines + [end])
    with open(path, "w") as f:
        f.write(head + body + tail)
    return True


def git_stamp():
    try:
        commit = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                text=True).stdout.strip()
    except OSError:
        commit = "unknown"
    return f"git {commit or 'unknown'}, {datetime.date.today().isoformat()}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", choices=sorted(CASES), help="run these cases")
    parser.add_argument("--skip-long", action="store_true", help="leave out the long cases")
    parser.add_argument("--reuse", action="store_true",
                        help="measure finished runs in the work folder again without running")
    parser.add_argument("--np", type=int, default=2, help="ranks per run (default 2)")
    parser.add_argument("--work", default=os.path.join(ROOT, "validation-runs"),
                        help="folder for the runs (default validation-runs/)")
    parser.add_argument("--binary", default=os.path.join(ROOT, "build", "release", "bin",
                                                         "sphremesh"))
    parser.add_argument("--list", action="store_true", help="list the cases and stop")
    args = parser.parse_args(argv)
    if args.list:
        for name, (func, long_case) in CASES.items():
            print(f"{name:16s} {'(long) ' if long_case else ''}{func.__doc__.split(chr(10))[0]}")
        return 0
    if MISSING_TOOLS is not None:
        print(f"validate: {MISSING_TOOLS}: run scripts/install-deps (scripts/validate does)",
              file=sys.stderr)
        return 2
    if not os.path.exists(args.binary):
        print(f"validate: {args.binary} is missing; scripts/validate builds it", file=sys.stderr)
        return 2
    os.makedirs(args.work, exist_ok=True)
    runner = Runner(os.path.abspath(args.work), args.np, args.reuse, args.binary)
    stamp = git_stamp() + f", {args.np} ranks"
    failed = []
    for name, (func, long_case) in CASES.items():
        if args.only and name not in args.only:
            continue
        if long_case and args.skip_long and not args.only:
            continue
        runner.commits = set()
        try:
            blocks = func(runner, args)
        except Exception as exc:  # a broken case must not hide the others' results
            failed.append(f"{name}: the measurement failed: {type(exc).__name__}: {exc}")
            continue
        made_by = (f", runs by git {' '.join(sorted(runner.commits))}"
                   if runner.commits else "")
        for block in blocks:
            target = os.path.join(ROOT, "README.md") if block.name == "channel" else \
                os.path.join(ROOT, "doc", "validation.md")
            # a case that measured nothing says why in its block instead of leaving it empty
            lines = block.lines or ["**Not measured:** " + "; ".join(block.failed +
                                                                     runner.failures)]
            if not replace_block(target, block.name, lines, stamp + made_by):
                failed.append(f"{block.name}: no validate:{block.name} markers in {target}")
            failed += block.failed
            print("\n".join([f"== {block.name}"] + lines), flush=True)
    failed += runner.failures
    if failed:
        print("\nvalidate: FAILED\n  " + "\n  ".join(failed), file=sys.stderr)
        return 1
    print("\nvalidate: every limit held")
    return 0


if __name__ == "__main__":
    sys.exit(main())
