#!/usr/bin/env python3
"""Plot velocity profiles u_x(y) of Couette/Poiseuille snapshots against the analytic solution.

  scripts/sph_plot_profiles.py output/poiseuille --output doc/poiseuille_profiles.png
  scripts/sph_plot_profiles.py output/poiseuille/poiseuille_000171.h5 ... --output p.png

Markers: every fluid particle; lines: the analytic solution at the snapshot's time; the
legend gives each time's relative L2 error (all fluid particles, all velocity components).
"""
import argparse
import os
import sys

import numpy as np

try:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:  # pragma: no cover
    sys.exit("sph_plot_profiles: matplotlib is missing; run scripts/install-deps and use .venv/bin/python")

import sph_analytic
import sph_snapshot
from sph_error_table import channel_parameters, snapshot_error


def exact_profile(par, case, y, t):
    if case == "poiseuille":
        return sph_analytic.poiseuille(y, t, par["force"], par["width"], par["nu"])
    return sph_analytic.couette(y, t, par["wall_speed"], par["width"], par["nu"])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("inputs", nargs="+", help="snapshot files or an output directory")
    parser.add_argument("--output", "-o", required=True, help="PNG file to write")
    parser.add_argument("--case", choices=["poiseuille", "couette"], help="default: the input's &run analytic")
    parser.add_argument("--skip-zero", action="store_true", default=True, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    files = []
    for item in args.inputs:
        if os.path.isdir(item):
            files.extend(sph_snapshot.list_snapshots(item))
        elif os.path.isfile(item):
            files.append(item)
        else:
            print(f"sph_plot_profiles: no such file or directory: {item}", file=sys.stderr)
            return 1
    if not files:
        print("sph_plot_profiles: no snapshots found", file=sys.stderr)
        return 1
    fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=150)
    colours = plt.cm.viridis(np.linspace(0.0, 0.85, len(files)))
    title = None
    for colour, path in zip(colours, files):
        try:
            snap = sph_snapshot.load(path)
            time, par, error, _ = snapshot_error(path, args.case)
        except (OSError, KeyError, ValueError) as problem:
            print(f"sph_plot_profiles: {path}: {problem}", file=sys.stderr)
            return 1
        case = args.case or par["case"]
        if time == 0:
            continue
        fluid = snap["kind"] == 0
        y = snap["position"][fluid, 1] - par["y0"]
        u = snap["velocity"][fluid, 0]
        ax.plot(y * 1e3, u * 1e6, "o", ms=2.0, color=colour, alpha=0.6)
        fine = np.linspace(0.0, par["width"], 400)
        ax.plot(fine * 1e3, exact_profile(par, case, fine, time) * 1e6, "-", color=colour, lw=1.2,
                label=f"t = {time:g} s  (L2 error {100 * error:.2f} %)")
        title = f"{case.capitalize()} flow, dx = L/{round(par['width'] / par['dx'])}"
    ax.set_xlabel("y [mm]")
    ax.set_ylabel("u_x [µm/s]")
    ax.set_title((title or "") + "\nmarkers: SPH fluid particles, lines: analytic solution", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(args.output)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
