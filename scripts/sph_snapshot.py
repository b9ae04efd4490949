#!/usr/bin/env python3
"""Read sphremesh snapshot files (schema: doc/output.md) into numpy arrays.

As a module (post-processing scripts):

    from sph_snapshot import load
    snap = load("output/poiseuille/poiseuille_007575.h5")
    x = snap["position"]            # (N, 3) float64, m
    fluid = snap["kind"] == 0
    t = snap["attrs"]["time"]       # s

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
except ImportError:  # pragma: no cover
    sys.exit("sph_snapshot: h5py is missing; run scripts/install-deps and use .venv/bin/python")

FORMAT = "sphremesh-snapshot"
FORMAT_VERSION = 1
FIELDS = ("position", "velocity", "density", "pressure", "mass", "smoothing_length", "energy",
          "id", "kind", "level", "rank")
KINDS = {0: "fluid", 1: "wall", 2: "virtual"}


def _plain(value):
    """An attribute as a Python str, int or float (h5py gives numpy scalars or bytes)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


def load(path):
    """All datasets of /particles (numpy arrays, N rows) and the root attributes.

    Returns a dict: one entry per dataset (``position``, ``velocity``: N x 3; the others: N;
    checkpoints have a few more) and ``attrs``, a dict of the root attributes as str, int or
    float. Raises ValueError for a file without the write_complete marker (a write that did
    not finish) or of another format.
    """
    with h5py.File(path, "r") as f:
        attrs = {key: _plain(value) for key, value in f.attrs.items()}
        if attrs.get("write_complete") != 1:
            raise ValueError(f"{path}: incomplete snapshot (no write_complete marker)")
        if attrs.get("format") != FORMAT or attrs.get("format_version") != FORMAT_VERSION:
            raise ValueError(f"{path}: not a {FORMAT} file of format version {FORMAT_VERSION} "
                             f"(format {attrs.get('format')!r}, "
                             f"version {attrs.get('format_version')!r})")
        data = {name: f["particles"][name][()] for name in f["particles"]}
    data["attrs"] = attrs
    return data


def list_snapshots(directory, case=None):
    """Snapshot files (not checkpoints) in a directory, sorted by step."""
    pattern = re.compile(r"^(?P<case>.+)_(?P<step>\d{6,})\.h5$")
    found = []
    for name in os.listdir(directory):
        match = pattern.match(name)
        if not match or "_checkpoint_" in name:
            continue
        if case and match.group("case") != case:
            continue
        found.append((int(match.group("step")), os.path.join(directory, name)))
    return [path for _, path in sorted(found)]


def summary(path):
    """A few lines describing a snapshot: header, particle counts, range of every field."""
    snap = load(path)
    a = snap["attrs"]
    n = len(snap["id"])
    lines = [f"{path}",
             f"  time {a['time']:.6g} s, step {a['step']}, dimension {a['dimension']}, "
             f"{a['nranks']} rank(s), {n} particles",
             f"  written {a.get('date', '?')} by {a.get('code_version', '?')}; "
             f"input {len(a.get('input', ''))} characters"]
    kinds, counts = np.unique(snap["kind"], return_counts=True)
    lines.append("  kinds: " + (", ".join(f"{KINDS.get(int(k), k)} {c}"
                                          for k, c in zip(kinds, counts)) or "none"))
    ranks, counts = np.unique(snap["rank"], return_counts=True)
    lines.append("  rows per rank: " + (", ".join(f"{int(r)}: {c}"
                                                  for r, c in zip(ranks, counts)) or "none"))
    for name in FIELDS:
        values = snap[name]
        if n == 0:
            lines.append(f"  {name:<20} (empty)")
        elif values.ndim == 2:
            for axis, label in enumerate("xyz"):
                column = values[:, axis]
                lines.append(f"  {name + '_' + label:<20} {column.min(): .6e} .. "
                             f"{column.max(): .6e}")
        else:
            lines.append(f"  {name:<20} {values.min(): .6e} .. {values.max(): .6e}")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(
        description="Print a summary of sphremesh snapshot files (schema: doc/output.md). "
                    "As a module, load(path) returns the datasets and attributes as a dict.")
    parser.add_argument("snapshots", nargs="+", metavar="FILE.h5", help="snapshot files")
    args = parser.parse_args(argv)
    status = 0
    for path in args.snapshots:
        try:
            print(summary(path))
        except (OSError, KeyError, ValueError) as problem:
            print(f"sph_snapshot: {path}: {problem}", file=sys.stderr)
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
