#!/usr/bin/env python3
"""Read sphremesh snapshot files (doc/output.md) into numpy arrays.

  scripts/sph_snapshot.py FILE.h5          # a one-screen summary of a snapshot
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

FIELDS = ("position", "velocity", "density", "pressure", "mass", "smoothing_length", "energy",
          "id", "kind", "level", "rank")
KINDS = {0: "fluid", 1: "wall", 2: "virtual"}


def _text(value):
    return value.decode() if isinstance(value, bytes) else str(value)


def load(path):
    """All datasets of /particles and the root attributes of a snapshot, as a dict."""
    with h5py.File(path, "r") as f:
        if "write_complete" not in f.attrs:
            raise ValueError(f"{path}: incomplete snapshot (no write_complete marker)")
        data = {name: f["particles"][name][:] for name in f["particles"]}
        attrs = {key: (_text(val) if isinstance(val, (bytes, str)) else val.item() if hasattr(val, "item") else val)
                 for key, val in f.attrs.items()}
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
    snap = load(path)
    a = snap["attrs"]
    lines = [f"{path}", f"  time {a['time']:.6g} s, step {a['step']}, dimension {a['dimension']}, "
             f"{a['nranks']} rank(s), written {a.get('date', '?')} by {a.get('code_version', '?')}"]
    kinds, counts = np.unique(snap["kind"], return_counts=True)
    lines.append("  particles: " + ", ".join(f"{KINDS.get(int(k), k)} {c}" for k, c in zip(kinds, counts)))
    for name in FIELDS:
        values = snap[name]
        if values.ndim == 2:
            for axis, label in enumerate("xyz"):
                lines.append(f"  {name + '_' + label:<20} {values[:, axis].min(): .6e} .. {values[:, axis].max(): .6e}")
        else:
            lines.append(f"  {name:<20} {values.min(): .6e} .. {values.max(): .6e}")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description="Print a summary of sphremesh snapshot files.")
    parser.add_argument("snapshots", nargs="+", help="HDF5 snapshot files")
    args = parser.parse_args(argv)
    for path in args.snapshots:
        try:
            print(summary(path))
        except (OSError, KeyError, ValueError) as problem:
            print(f"sph_snapshot: {path}: {problem}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
