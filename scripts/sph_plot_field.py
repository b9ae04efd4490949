#!/usr/bin/env python3
"""Plot one particle field of a snapshot, coloured on the particles.

  scripts/sph_plot_field.py output/poiseuille/poiseuille_007575.h5 --field velocity_x -o u.png
  scripts/sph_plot_field.py FILE.h5 --field rank --kinds fluid,wall -o ranks.png

Fields: position/velocity components (velocity_x, ...), velocity_magnitude, density,
pressure, mass, smoothing_length, energy, id, kind, level, rank. In 3D a slice
|z - z0| < dx/2 is shown (--z, default mid-box).
"""
import argparse
import sys

import numpy as np

try:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:  # pragma: no cover
    sys.exit("sph_plot_field: matplotlib is missing; run scripts/install-deps and use .venv/bin/python")

import sph_snapshot

KIND_NAMES = {"fluid": 0, "wall": 1, "virtual": 2}


def field_values(snap, name):
    if name in ("velocity_magnitude", "speed"):
        return np.linalg.norm(snap["velocity"], axis=1)
    for vector in ("velocity", "position"):
        for axis, label in enumerate("xyz"):
            if name == f"{vector}_{label}":
                return snap[vector][:, axis]
    if name in snap and name != "attrs" and snap[name].ndim == 1:
        return snap[name]
    raise KeyError(f"unknown field '{name}'")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("snapshot", help="HDF5 snapshot file")
    parser.add_argument("--field", "-f", default="velocity_magnitude", help="field to colour by")
    parser.add_argument("--kinds", default="fluid,wall", help="comma-separated: fluid, wall, virtual")
    parser.add_argument("--z", type=float, help="3D: slice position (default: middle of the particles)")
    parser.add_argument("--output", "-o", required=True, help="PNG file to write")
    args = parser.parse_args(argv)
    try:
        snap = sph_snapshot.load(args.snapshot)
        values = field_values(snap, args.field)
        wanted = [KIND_NAMES[k.strip()] for k in args.kinds.split(",") if k.strip()]
    except KeyError as problem:
        print(f"sph_plot_field: {problem}; kinds are fluid, wall, virtual", file=sys.stderr)
        return 1
    except (OSError, ValueError) as problem:
        print(f"sph_plot_field: {args.snapshot}: {problem}", file=sys.stderr)
        return 1
    pos = snap["position"]
    keep = np.isin(snap["kind"], wanted)
    title_extra = ""
    if int(snap["attrs"]["dimension"]) == 3:
        z0 = args.z if args.z is not None else 0.5 * (pos[:, 2].min() + pos[:, 2].max())
        half = 0.5 * np.median(snap["smoothing_length"]) / 1.3
        keep &= np.abs(pos[:, 2] - z0) <= half * 1.0001
        title_extra = f", slice z = {z0:.4g} m"
    if not keep.any():
        print("sph_plot_field: no particles to show (check --kinds and --z)", file=sys.stderr)
        return 1
    fig, ax = plt.subplots(figsize=(6.4, 5.4), dpi=150)
    extent = np.ptp(pos[keep, :2], axis=0).max()
    size = max(1.0, 2.0e4 / keep.sum())
    sc = ax.scatter(pos[keep, 0] * 1e3, pos[keep, 1] * 1e3, c=values[keep], s=size, cmap="viridis",
                    linewidths=0)
    fig.colorbar(sc, ax=ax, label=args.field)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(f"{args.field} at t = {snap['attrs']['time']:g} s{title_extra}", fontsize=10)
    fig.tight_layout()
    fig.savefig(args.output)
    print(f"wrote {args.output} ({keep.sum()} particles, extent {extent:.3g} m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
