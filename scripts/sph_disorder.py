#!/usr/bin/env python3
"""Disorder statistics of the fluid particles of one or two sphremesh snapshots.

    .venv/bin/python scripts/sph_disorder.py SNAP1.h5 [SNAP2.h5] [--level L]

For the fluid particles (kind 0) of each file: their count, the mean and the coefficient of
variation (std / mean) of the nearest-neighbour distance, the minimum pair distance (the
smallest nearest-neighbour distance), the density spread (min, max, std / mean) and the spread
of the kernel sum of volumes, sum_j (m_j / rho_j) W(r_ij, h_i) (cubic B-spline at each fluid
particle's smoothing length, over the fluid, wall and virtual particles of its level). That
sum is 1 on an even set; it shows the holes and clumps at the kernel's scale that the nearest
distances miss (Morris' L/25 cylinder flow at 1500 s: 0.015; refined, 0.16 before the refined
set was relaxed, 0.06 after). With two
files (say before and after a remesh) also the ratios second / first of the count, the mean
nearest-neighbour distance and its coefficient of variation: a refinement in 2D should show
a count ratio of 4 and a mean ratio of 1/2, a coarsening the inverse, with a CoV ratio near 1
if the disorder was kept.

Distances honour the periodic box: the box is the run's &domain box_lo .. box_hi, and an axis
is periodic when its lower face has boundary = 'periodic' (the input text stored in every
file, as sph_snapshot.geometry reads it); other axes are open. Only the fluid particles are
measured (wall and virtual particles are left out), of one level of a multi-resolution
snapshot (--level; its levels' spacings differ by 2, so a mix is no disorder measure); its
kernel sums need the virtual particles (&refinement write_virtual), n/a without them.
Needs numpy, scipy and h5py (scripts/install-deps puts them in .venv). As a module,
disorder(path, level) returns the figures as a dict.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from sph_snapshot import SnapshotError, geometry, load, namelist  # noqa: E402

try:
    from scipy.spatial import cKDTree
except ImportError:  # pragma: no cover - a message, not a traceback
    sys.exit("sph_disorder: scipy is missing; run scripts/install-deps and use .venv/bin/python")


def periodic_axes(snap, dim):
    """Which of the first dim axes are periodic, from the input's &domain boundary list
    (xlo, xhi, ylo, yhi, zlo, zhi); all open if the input cannot be read."""
    try:
        faces = namelist(snap)["domain"]["boundary"]
        if isinstance(faces, str):
            faces = [faces]
        return [str(faces[2 * a]).strip().lower() == "periodic" for a in range(dim)]
    except Exception:  # no or odd input text: measure as an open set
        return [False] * dim


def periodic_frame(points, lo, hi, periodic):
    """points moved into [0, size) along the periodic axes of the box [lo, hi), and the box
    sizes for cKDTree (None for an open set): an open axis gets a period longer than
    twice its extent, through which no pair is ever nearer than directly."""
    if not any(periodic):
        return points, None
    shifted = points - lo
    span = np.ptp(points, axis=0)
    size = np.empty(len(lo))
    for a, wrap in enumerate(periodic):
        if wrap:
            size[a] = hi[a] - lo[a]
            shifted[:, a] = np.mod(shifted[:, a], size[a])
            # mod may round a value just below the length up to it
            shifted[shifted[:, a] >= size[a], a] = 0.0
        else:
            shifted[:, a] = points[:, a] - points[:, a].min()
            size[a] = 3.0 * span[a] + 1.0
    return shifted, size


def nearest_distances(points, lo, hi, periodic):
    """Nearest-neighbour distance of every point (N x dim), minimum image along the periodic
    axes of the box [lo, hi)."""
    if len(points) < 2:
        return np.zeros(0)
    points, size = periodic_frame(points, lo, hi, periodic)
    dist, _ = cKDTree(points, boxsize=size).query(points, k=2)
    return dist[:, 1]


def cubic_spline(r, h, dim):
    """The cubic B-spline kernel W(r, h) (support 2 h) in dim dimensions."""
    q = r / h
    norm = {1: 2.0 / 3.0, 2: 10.0 / (7.0 * np.pi), 3: 1.0 / np.pi}[dim] / h**dim
    return norm * np.where(q < 1.0, 1.0 - 1.5 * q**2 + 0.75 * q**3,
                           np.where(q < 2.0, 0.25 * (2.0 - q)**3, 0.0))


def volume_sums(snap, geo, periodic):
    """sum_j (m_j / rho_j) W(r_ij, h_i) at every fluid particle i (the module docstring)."""
    dim = geo["dimension"]
    kind = snap["kind"]
    level = snap.get("level")
    level = np.zeros(len(kind), dtype=int) if level is None else np.asarray(level)
    points, size = periodic_frame(np.asarray(snap["position"], dtype=float)[:, :dim],
                                  geo["box_lo"][:dim], geo["box_hi"][:dim], periodic)
    volume = np.asarray(snap["mass"], dtype=float) / np.asarray(snap["density"], dtype=float)
    h = np.asarray(snap["smoothing_length"], dtype=float)
    fluid = np.flatnonzero(kind == 0)
    sums = np.zeros(len(fluid))
    for lv in np.unique(level[fluid]):
        mine = fluid[level[fluid] == lv]
        others = np.flatnonzero((level == lv) & (kind <= 2))
        pairs = cKDTree(points[mine], boxsize=size).sparse_distance_matrix(
            cKDTree(points[others], boxsize=size), 2.0 * h[mine].max(), output_type="ndarray")
        i, j, r = pairs["i"], pairs["j"], pairs["v"]
        # (the ndarray output keeps the pairs at r = 0, each particle with itself among them)
        w = cubic_spline(r, h[mine][i], dim) * volume[others][j]
        sums[np.searchsorted(fluid, mine)] = np.bincount(i, weights=w, minlength=len(mine))
    return sums


def disorder(path, level=None):
    """The figures of one snapshot as a dict: count, mean_nn, cov_nn, min_pair, rho_min,
    rho_max, rho_spread (std / mean of the density), volume_sum_mean and volume_sum_spread
    (std / mean of the kernel sums of volumes; NaN for a multi-resolution snapshot without
    its virtual particles), dimension, periodic (per axis), nearest (each particle's
    nearest distance, the array the figures come from). A multi-resolution snapshot's
    levels have spacings a factor 2 apart: their fluid is measured one level at a time
    (level; refused without it), as mixed they read as a disorder of 0.3 (CoV) on two
    lattices."""
    snap = load(path, check_format=False)
    geo = geometry(snap)
    dim = geo["dimension"]
    kind = snap["kind"]
    levels = np.zeros(len(kind), dtype=int) if snap.get("level") is None else \
        np.asarray(snap["level"])
    present = sorted(set(levels[kind == 0].tolist()))
    if level is None and len(present) > 1:
        raise SnapshotError(f"{path}: holds the fluid of levels {present}: give --level")
    fluid = kind == 0
    if level is not None:
        fluid &= levels == level
    points = np.asarray(snap["position"], dtype=float)[fluid][:, :dim]
    rho = np.asarray(snap["density"], dtype=float)[fluid]
    periodic = periodic_axes(snap, dim)
    if len(points) < 2:
        raise SnapshotError(f"{path}: fewer than two fluid particles, no distances to measure")
    d = nearest_distances(points, geo["box_lo"][:dim], geo["box_hi"][:dim], periodic)
    mean = float(d.mean())
    # (next to an interface a level's kernel sums need the virtual particles of that level:
    # without them, 0.079 where they give 3e-10)
    if len(present) > 1 and not np.any(kind == 2):
        sums = np.full(int(fluid.sum()), np.nan)
    else:
        sums = volume_sums(snap, geo, periodic)[fluid[kind == 0]]
    return {"path": path, "dimension": dim, "periodic": periodic, "count": int(len(points)),
            "mean_nn": mean, "cov_nn": float(d.std() / mean) if mean > 0 else float("nan"),
            "min_pair": float(d.min()), "rho_min": float(rho.min()),
            "rho_max": float(rho.max()), "rho_spread": float(rho.std() / rho.mean()),
            "volume_sum_mean": float(sums.mean()),
            "volume_sum_spread": float(sums.std() / sums.mean()), "nearest": d}


def report(stats):
    axes = "".join(a for a, p in zip("xyz", stats["periodic"]) if p) or "none"
    return "\n".join([
        f"{stats['path']}: {stats['dimension']}D, periodic axes: {axes}",
        f"  fluid particles          {stats['count']}",
        f"  nearest-neighbour mean   {stats['mean_nn']:.6g} m",
        f"  nearest-neighbour CoV    {stats['cov_nn']:.6g}",
        f"  minimum pair distance    {stats['min_pair']:.6g} m",
        f"  density min / max        {stats['rho_min']:.6g} / {stats['rho_max']:.6g} kg/m^3",
        f"  density std / mean       {stats['rho_spread']:.6g}",
        f"  kernel sum of volumes    mean {stats['volume_sum_mean']:.6g}, "
        f"std / mean {stats['volume_sum_spread']:.6g}" if not np.isnan(stats["volume_sum_mean"])
        else "  kernel sum of volumes    n/a (a multi-resolution snapshot without its virtual "
        "particles: &refinement write_virtual = .true. writes them)"])


def ratios(first, second):
    """second / first for the count, the mean and the CoV of the nearest distances."""
    def ratio(a, b):
        return b / a if a != 0 else float("inf") if b != 0 else float("nan")
    return {"count": ratio(first["count"], second["count"]),
            "mean_nn": ratio(first["mean_nn"], second["mean_nn"]),
            "cov_nn": ratio(first["cov_nn"], second["cov_nn"])}


def main(argv=None):
    parser = argparse.ArgumentParser(
        description="Disorder statistics of the fluid particles of one or two snapshots: "
                    "count, mean and coefficient of variation of the nearest-neighbour "
                    "distance, minimum pair distance, density spread; with two files the "
                    "ratios second / first (periodic axes from the run's input).")
    parser.add_argument("snapshots", nargs="+", metavar="SNAP.h5", help="one or two files")
    parser.add_argument("--level", type=int,
                        help="the resolution level measured (a multi-resolution snapshot)")
    args = parser.parse_args(argv)
    if len(args.snapshots) > 2:
        parser.error("give one or two snapshot files")
    try:
        stats = [disorder(path, args.level) for path in args.snapshots]
    except (OSError, KeyError, ValueError) as problem:
        print(f"sph_disorder: {problem}", file=sys.stderr)
        return 1
    print("\n".join(report(s) for s in stats))
    if len(stats) == 2:
        r = ratios(*stats)
        print("second / first:")
        print(f"  count ratio              {r['count']:.6g}")
        print(f"  mean nearest ratio       {r['mean_nn']:.6g}")
        print(f"  CoV ratio                {r['cov_nn']:.6g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
