#!/usr/bin/env python3
"""Read sphremesh snapshot files (schema: doc/output.md) into numpy arrays.

As a module (post-processing scripts, with scripts/ on sys.path):

    from sph_snapshot import header, list_snapshots, load, spacing
    snap = load("output/poiseuille/poiseuille_007575.h5")
    x = snap["position"]            # (N, 3) float64, m
    fluid = snap["kind"] == 0
    t = snap["attrs"]["time"]       # s (also snap["time"])
    dx = spacing(snap)              # m, level 0 when written (attribute dx, else the input's)
    files = list_snapshots("output/poiseuille")      # sorted by step
    head = header(files[-1])        # the checks and attributes without the particles

As a command, a one-screen summary of each file:

    scripts/sph_snapshot.py FILE.h5 [FILE.h5 ...]

Needs numpy and h5py (scripts/install-deps puts them in .venv; run with .venv/bin/python).
"""
import argparse
import os
import re
import sys

import numpy as np

try:
    import h5py
except ImportError:  # pragma: no cover - a message, not a traceback
    sys.exit("sph_snapshot: h5py is missing; run scripts/install-deps and use .venv/bin/python")

FORMAT = "sphremesh-snapshot"
FORMAT_VERSION = 1
FIELDS = ("position", "velocity", "density", "pressure", "mass", "smoothing_length", "energy",
          "id", "kind", "level", "rank")
KINDS = {0: "fluid", 1: "wall", 2: "virtual"}
KIND_CODES = {name: code for code, name in KINDS.items()}
# Root attributes also copied to the top level of load()'s dict, for convenience.
HEADER = ("time", "step", "dimension", "input", "code_version", "nranks", "date")
SNAPSHOT_NAME = re.compile(r"^(?P<case>.+)_(?P<step>\d{6,})\.h5$")


class SnapshotError(ValueError):
    """A file that is not a readable, complete sphremesh snapshot (message names the file)."""


def _plain(value):
    """An attribute as a Python str, int or float (h5py gives numpy scalars or bytes)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.shape == (1,):
        value = value[0]
    if isinstance(value, np.bytes_):
        return bytes(value).decode("utf-8", "replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


def _checked_attrs(f, path, check_format):
    """The root attributes of an open file as plain values, after the checks every reader
    makes: a sphremesh file, its write complete, of this format (check_format)."""
    attrs = {key: _plain(value) for key, value in f.attrs.items()}
    # (a file sphremesh did not write: an initial particle file, another tool's, was
    # called an incomplete snapshot, the message of a write that crashed)
    if "format" not in attrs and "write_complete" not in attrs:
        raise SnapshotError(f"{path}: not a sphremesh snapshot or checkpoint (no "
                            "format attribute: an initial particle file, or another "
                            "tool's?)")
    if attrs.get("write_complete") != 1:
        raise SnapshotError(f"{path}: incomplete snapshot (no write_complete marker)")
    if check_format and (attrs.get("format") != FORMAT
                         or attrs.get("format_version") != FORMAT_VERSION):
        raise SnapshotError(f"{path}: not a {FORMAT} file of format version "
                            f"{FORMAT_VERSION} (format {attrs.get('format')!r}, "
                            f"version {attrs.get('format_version')!r})")
    for key in ("time", "step", "dimension"):
        if key not in attrs:
            raise SnapshotError(f"{path}: no root attribute '{key}'")
    return attrs


def _check_path(path):
    if os.path.isdir(path):
        # (h5py's errno dump, "Unable to synchronously open file (... errno = 21 ...)")
        raise SnapshotError(f"{path}: a directory, not a snapshot file")
    if not os.path.isfile(path):
        raise SnapshotError(f"{path}: no such file")


def _with_header(data, attrs, path):
    data["attrs"] = attrs
    for key in HEADER:
        if key in attrs:
            data[key] = attrs[key]
    data["path"] = path
    return data


def header(path, check_format=True):
    """The root attributes of a snapshot or checkpoint without its particles, after the
    checks of load(): a dict with ``attrs``, ``path`` and the header attributes (``time``,
    ``input``, ...) at the top level, as load() gives them. For the spacing (spacing()) or the
    input of a file whose particles are not needed. Raises SnapshotError as load()."""
    _check_path(path)
    try:
        with h5py.File(path, "r") as f:
            attrs = _checked_attrs(f, path, check_format)
    except OSError as problem:
        raise SnapshotError(f"{path}: not a readable HDF5 file ({problem})") from None
    return _with_header({}, attrs, path)


def load(path, check_format=True):
    """All datasets of /particles (numpy arrays, N rows) and the root attributes.

    Returns a dict: one entry per dataset (``position``, ``velocity``: N x 3; the others: N;
    checkpoints have a few more), ``attrs`` (every root attribute as str, int or float, strings
    decoded) and, for convenience, the header attributes ``time``, ``step``, ``dimension``,
    ``input``, ... also at the top level. Raises SnapshotError (a ValueError) for a missing
    or unreadable file, a file without the write_complete marker (a write that did not
    finish) or of another format.
    """
    _check_path(path)
    try:
        with h5py.File(path, "r") as f:
            attrs = _checked_attrs(f, path, check_format)
            if "particles" not in f or not isinstance(f["particles"], h5py.Group):
                raise SnapshotError(f"{path}: no /particles group")
            data = {name: f["particles"][name][()] for name in f["particles"]
                    if isinstance(f["particles"][name], h5py.Dataset)}
    except OSError as problem:
        raise SnapshotError(f"{path}: not a readable HDF5 file ({problem})") from None
    missing = [name for name in FIELDS if name not in data]
    if missing:
        raise SnapshotError(f"{path}: /particles lacks {', '.join(missing)}")
    return _with_header(data, attrs, path)


def namelist(snap):
    """The run's resolved input (f90nml Namelist) from a load() result or the input text."""
    import f90nml  # imported here: the summary works without it
    text = snap if isinstance(snap, str) else snap["attrs"].get("input", "")
    return f90nml.reads(text)


def spacing(snap):
    """The spacing of level 0 (m) when a file was written: its root attribute ``dx`` where it
    has one, else the &domain dx of its stored input.

    The stored input keeps the spacing the run began with: after an in-run remesh (&remesh
    mode = 'refine' or 'coarsen') or a restart at another spacing only the attribute is
    right (checkpoints carry it, snapshots since the program writes it; an older snapshot
    has only its input). ``snap``: a load() or header() result. Every script that needs the
    spacing takes it from here. Raises SnapshotError (naming the file) when neither gives a
    positive spacing."""
    attrs = snap["attrs"]
    path = snap.get("path", "snapshot")
    if "dx" in attrs:
        stored = attrs["dx"]
        if (isinstance(stored, (int, float)) and not isinstance(stored, bool)
                and np.isfinite(stored) and stored > 0):
            return float(stored)
        raise SnapshotError(f"{path}: root attribute dx = {stored!r} is not a spacing")
    try:
        dx = float(namelist(attrs.get("input", ""))["domain"]["dx"])
    except Exception as problem:  # f90nml's errors, a missing group or key
        raise SnapshotError(f"{path}: no root attribute dx and no &domain dx in the stored "
                            f"input ({type(problem).__name__}: {problem})") from None
    if not (np.isfinite(dx) and dx > 0):
        raise SnapshotError(f"{path}: the stored input's &domain dx = {dx!r} is not a spacing")
    return dx


def geometry(snap):
    """dimension, dx, box_lo (3), box_hi (3) of a loaded snapshot: dx from spacing() (the
    file's attribute dx, else its input's), the box from its input text; the box and dx are
    estimated from the particles if neither can be read."""
    dim = int(snap["attrs"]["dimension"])
    try:
        domain = namelist(snap)["domain"]
        lo = np.zeros(3)
        hi = np.zeros(3)
        lo[:dim] = np.asarray(domain["box_lo"], dtype=float)[:dim]
        hi[:dim] = np.asarray(domain["box_hi"], dtype=float)[:dim]
        # (a remeshed run's spacing: its input keeps the one the run began with, an L/10
        # coarsening was reported as L/20)
        dx = spacing(snap)
    except Exception:  # no or odd input text: estimate from the particles
        pos = snap["position"]
        h = snap["smoothing_length"]
        dx = float(np.median(h) / 1.3) if len(h) else 1.0
        fluid = snap["kind"] == 0
        pts = pos[fluid] if fluid.any() else pos
        lo = pts.min(axis=0) - dx / 2 if len(pts) else np.zeros(3)
        hi = pts.max(axis=0) + dx / 2 if len(pts) else np.ones(3)
    return {"dimension": dim, "dx": dx, "box_lo": lo, "box_hi": hi}


_PREFIXES = ((1e-9, "n"), (1e-6, "\u00b5"), (1e-3, "m"), (1.0, ""), (1e3, "k"))


def si_scale(largest, unit):
    """(factor, label) such that largest / factor lies in [1, 1000): si_scale(2.5e-5, "m/s")
    gives (1e-6, "\u00b5m/s"). For axis and colour-bar labels of plots."""
    factor, prefix = 1.0, ""
    largest = abs(float(largest))
    if largest > 0 and np.isfinite(largest):
        for f, p in _PREFIXES:
            if largest >= f * 0.999:
                factor, prefix = f, p
    return factor, prefix + unit


def list_snapshots(directory, case=None):
    """Snapshot files (not checkpoints, failure snapshots or *.tmp) in a directory, by step.

    ``case`` keeps only <case>_<step>.h5; without it, all cases are listed.
    Raises SnapshotError if the directory does not exist."""
    if not os.path.isdir(directory):
        raise SnapshotError(f"{directory}: no such directory")
    found = []
    for name in os.listdir(directory):
        match = SNAPSHOT_NAME.match(name)
        # (a failure snapshot is the state a run stopped in, not one of its output times)
        if not match or match.group("case").endswith(("_checkpoint", "_failure")):
            continue
        if case and match.group("case") != case:
            continue
        found.append((int(match.group("step")), name, os.path.join(directory, name)))
    return [path for _, _, path in sorted(found)]


def complete_snapshots(directory, case, tool):
    """(time, path) of the complete snapshots <case>_<step>.h5 in a directory, sorted by time.

    A file that h5py cannot open (a copy cut short, a disk that filled) or that lacks the
    write_complete marker is skipped with one line on stderr naming it and ``tool``: the
    other snapshots still answer. Raises SnapshotError if the directory does not exist."""
    found = []
    for path in list_snapshots(directory, case):
        try:
            with h5py.File(path, "r") as f:
                if _plain(f.attrs.get("write_complete", 0)) != 1 or "time" not in f.attrs:
                    raise SnapshotError("incomplete (no write_complete marker)")
                found.append((float(_plain(f.attrs["time"])), path))
        except (OSError, SnapshotError) as problem:
            reason = str(problem) if isinstance(problem, SnapshotError) else "not readable"
            print(f"{tool}: skipped {path}: {reason}", file=sys.stderr)
    return sorted(found)


def _vector(values, dim):
    return "(" + ", ".join(f"{v:.6g}" for v in values[:dim]) + ")"


def _range(values):
    if values.dtype.kind in "iu":
        return f"{values.min():>14d} {values.max():>14d}"
    return f"{values.min():>14.6e} {values.max():>14.6e}"


def summary(path):
    """A few lines describing a snapshot: header, particle counts, range of every field."""
    snap = load(path, check_format=False)
    a = snap["attrs"]
    n = len(snap["id"])
    lines = [f"{path}",
             f"  time {a['time']:.6g} s, step {a['step']}, dimension {a['dimension']}, "
             f"{a.get('nranks', '?')} rank(s), {n} particles",
             f"  written {a.get('date', '?')} by {a.get('code_version', '?')}; "
             f"format {a.get('format', '?')} v{a.get('format_version', '?')}; "
             f"input {len(a.get('input', ''))} characters"]
    # (a failure snapshot: the state a run stopped in, and why)
    if a.get("failure"):
        lines.append(f"  failure snapshot: {a['failure']}")
    try:
        run = namelist(snap)["run"]
        geo = geometry(snap)
        lines.append(f"  case {run.get('case_name', '?')}, analytic {run.get('analytic', 'none')}, "
                     f"dx {geo['dx']:.4g} m, box {_vector(geo['box_lo'], geo['dimension'])} .. "
                     f"{_vector(geo['box_hi'], geo['dimension'])} m")
    except Exception:  # the summary does not need the input
        pass
    kinds, counts = np.unique(snap["kind"], return_counts=True)
    lines.append("  kinds: " + (", ".join(f"{KINDS.get(int(k), k)} {c}"
                                          for k, c in zip(kinds, counts)) or "none"))
    ranks, counts = np.unique(snap["rank"], return_counts=True)
    shown = ", ".join(f"{int(r)}: {c}" for r, c in list(zip(ranks, counts))[:16])
    if len(ranks) > 16:
        shown += f", ... ({len(ranks)} ranks)"
    lines.append("  rows per rank: " + (shown or "none"))
    levels, counts = np.unique(snap["level"], return_counts=True)
    lines.append("  rows per level: " + (", ".join(f"{int(r)}: {c}"
                                                   for r, c in zip(levels, counts)) or "none"))
    lines.append(f"  {'field':<20} {'min':>14} {'max':>14}")
    for name in FIELDS:
        values = snap[name]
        if n == 0:
            lines.append(f"  {name:<20} (empty)")
        elif values.ndim == 2:
            for axis, label in enumerate("xyz"):
                lines.append(f"  {name + '_' + label:<20} {_range(values[:, axis])}")
        else:
            lines.append(f"  {name:<20} {_range(values)}")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(
        description="Print a summary of sphremesh snapshot files (time, step, particles per "
                    "kind, rank and level, range of every field; schema: doc/output.md). "
                    "As a module, load(path) returns the datasets and attributes as a dict.")
    parser.add_argument("snapshots", nargs="+", metavar="FILE.h5",
                        help="snapshot files, or an output directory (all its snapshots)")
    args = parser.parse_args(argv)
    status = 0
    first = True
    for item in args.snapshots:
        try:
            paths = list_snapshots(item) if os.path.isdir(item) else [item]
            if not paths:
                raise SnapshotError(f"{item}: no snapshot files (<case>_<step>.h5)")
        except (OSError, ValueError) as problem:
            print(f"sph_snapshot: {problem}", file=sys.stderr)
            status = 1
            continue
        for path in paths:
            # (a folder's first unreadable file, one cut short, hid the others' summaries)
            try:
                text = summary(path)
            except (OSError, KeyError, ValueError) as problem:
                print(f"sph_snapshot: {problem}", file=sys.stderr)
                status = 1
                continue
            print(text if first else "\n" + text)
            first = False
    return status


if __name__ == "__main__":
    sys.exit(main())
