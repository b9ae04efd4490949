#!/usr/bin/env python3
"""Compare the particles of two sphremesh snapshots (or checkpoints), matched by global id.

    sph_compare.py A.h5 B.h5 [--tolerance T] [--ignore rank ...]

Every particle dataset present in both files is compared after sorting both by id: integer
datasets must agree exactly, real ones to within T relative to the dataset's largest magnitude
(T = 0, the default, asks for bitwise equality); the times alike, relative to the larger
(runs on other rank counts can end a few ulps apart after many steps). Velocities are also reported relative to the
peak speed, the measure used for rank-count invariance. Exit status 0 when everything agrees,
1 otherwise (also when the ids differ), 2 on unreadable input.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import sph_snapshot  # noqa: E402


def load(path):
    """(time, the /particles datasets sorted by id) of a snapshot or checkpoint, after the
    loader's checks (a file without write_complete, another tool's file or one without a
    field such as velocity is refused: the last one was reported as agreeing); status 2 with
    one message when the file cannot be used."""
    try:
        snap = sph_snapshot.load(path)
    except (OSError, ValueError) as problem:
        # (status 2, as the docstring says: an unreadable file is not a difference)
        print(f"sph_compare: {problem}", file=sys.stderr)
        sys.exit(2)
    # (load() gives the datasets as arrays beside the header's plain values)
    data = {name: values for name, values in snap.items() if isinstance(values, np.ndarray)}
    order = np.argsort(data["id"], kind="stable")
    return float(snap["time"]), {name: values[order] for name, values in data.items()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("a")
    parser.add_argument("b")
    parser.add_argument("--tolerance", type=float, default=0.0,
                        help="largest relative difference accepted (default 0: bitwise)")
    parser.add_argument("--ignore", nargs="*", default=["rank"],
                        help="datasets not compared (default: rank)")
    args = parser.parse_args(argv)
    # (-1 or nan were taken, and then the same file was said to DIFFER)
    if not (np.isfinite(args.tolerance) and args.tolerance >= 0):
        parser.error(f"--tolerance must be a finite number >= 0 (got {args.tolerance:g})")

    time_a, a = load(args.a)
    time_b, b = load(args.b)
    ok = True
    if abs(time_a - time_b) > args.tolerance * max(abs(time_a), abs(time_b)):
        print(f"time differs: {time_a!r} vs {time_b!r}")
        ok = False
    elif time_a != time_b:
        print(f"time {time_a!r} vs {time_b!r}: within the tolerance")
    if a["id"].shape != b["id"].shape or np.any(a["id"] != b["id"]):
        print(f"ids differ: {a['id'].size} vs {b['id'].size} particles")
        return 1
    for name in sorted(set(a) & set(b)):
        if name in args.ignore:
            continue
        x, y = a[name], b[name]
        if x.shape != y.shape:
            print(f"{name:18s} shapes differ {x.shape} vs {y.shape}")
            ok = False
            continue
        if np.issubdtype(x.dtype, np.integer):
            bad = int(np.count_nonzero(x != y))
            print(f"{name:18s} {'identical' if bad == 0 else f'{bad} values differ'}")
            ok &= bad == 0
            continue
        # (a NaN in both at the same place is the same value: a failure snapshot and its
        # copy were reported as differing)
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        differ = int(np.count_nonzero(~same))
        scale = float(np.nanmax(np.abs(x))) if np.isfinite(x).any() else 0.0
        gaps = np.where(same, 0.0, np.abs(x - y))
        gaps[np.isnan(gaps)] = np.inf
        worst = float(np.max(gaps)) if x.size else 0.0
        relative = worst / scale if scale > 0 else worst
        extra = ""
        if name == "velocity" and x.size:
            peak = float(np.max(np.linalg.norm(x, axis=1)))
            if peak > 0:
                extra = f", max |dv|/peak {worst / peak:.3e}"
        status = "bitwise identical" if differ == 0 else \
            f"{differ} values differ, max relative {relative:.3e}{extra}"
        print(f"{name:18s} {status}")
        ok &= differ == 0 if args.tolerance == 0 else relative <= args.tolerance
    only = sorted((set(a) ^ set(b)) - set(args.ignore))
    if only:
        print("datasets in one file only:", ", ".join(only))
    print("agree" if ok else "DIFFER")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
