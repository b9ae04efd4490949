#!/usr/bin/env python3
"""Plot velocity profiles u_x(y) of Couette/Poiseuille snapshots against the analytic solution.

  scripts/sph_plot_profiles.py output/poiseuille --output poiseuille_profiles.png
  scripts/sph_plot_profiles.py output/poiseuille/poiseuille_000171.h5 ... --output p.png
  scripts/sph_plot_profiles.py output/couette --average --steady --output c.png

Markers: every fluid particle (or, with --average, the mean of each particle row, with its
spread as error bars); lines: the analytic solution at each snapshot's time, one colour per
time; the legend gives each time's relative L2 error (all fluid particles, all velocity
components, as scripts/sph_error_table.py). Works for 2D and 3D snapshots (u_x against y
of all fluid particles). The t = 0 snapshot (fluid at rest) is left out unless --initial.
"""
import argparse
import os
import sys

import numpy as np

try:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    import f90nml  # noqa: F401  (sph_error_table needs it; fail here with a message)
except ImportError as missing:  # pragma: no cover - a message, not a traceback
    sys.exit(f"sph_plot_profiles: {missing.name} is missing; run scripts/install-deps "
             "and use .venv/bin/python")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import sph_analytic  # noqa: E402
import sph_snapshot  # noqa: E402
from sph_error_table import channel_parameters, snapshot_error, wall_distance  # noqa: E402

si_scale = sph_snapshot.si_scale


def exact_profile(par, case, y, t):
    """Analytic velocity along the flow at distances y from the resting wall (wall_distance),
    time t (inf: steady)."""
    exact = sph_analytic.channel(case, y, t, par)
    if exact is not None:
        return exact
    raise ValueError(f"no analytic solution for case '{case}' (give --case poiseuille|couette)")


def percent(error):
    """A relative error as a percentage, readable also when it is tiny."""
    value = 100.0 * error
    return f"{value:.2f} %" if value >= 0.01 or value == 0 else f"{value:.1e} %"


def row_means(y, u, dx):
    """Mean and standard deviation of u over each row of particles (rows dx apart)."""
    row = np.rint(y / dx - 0.5).astype(np.int64)
    rows = np.unique(row)
    ym = np.array([y[row == r].mean() for r in rows])
    um = np.array([u[row == r].mean() for r in rows])
    us = np.array([u[row == r].std() for r in rows])
    return ym, um, us


def level_row_means(y, u, level, dx):
    """row_means for each refinement level at its own spacing dx / 2^level (a multi-resolution
    run's fine rows lie dx/2 apart: binned at dx they were averaged in pairs), sorted by y."""
    parts = [row_means(y[level == lv], u[level == lv], dx / 2.0**lv) for lv in np.unique(level)]
    ym, um, us = (np.concatenate([part[k] for part in parts]) for k in range(3))
    order = np.argsort(ym, kind="stable")
    return ym[order], um[order], us[order]


def collect(inputs):
    files = []
    for item in inputs:
        if os.path.isdir(item):
            found = sph_snapshot.list_snapshots(item)
            if not found:
                raise ValueError(f"{item}: no snapshot files (<case>_<step>.h5) in this directory")
            files.extend(found)
        elif os.path.isfile(item):
            files.append(item)
        else:
            raise ValueError(f"{item}: no such file or directory")
    return files


def main(argv=None):
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Markers: SPH fluid particles; lines: analytic solution; legend: time and "
               "relative L2 error. The output format follows the extension (png, pdf, svg).")
    parser.add_argument("inputs", nargs="+", metavar="SNAPSHOT_OR_DIR",
                        help="snapshot files (.h5) or an output directory (all its snapshots)")
    parser.add_argument("--output", "-o", required=True, metavar="FILE.png", help="image to write")
    parser.add_argument("--case", choices=["poiseuille", "couette"],
                        help="analytic solution (default: the input's &run analytic)")
    parser.add_argument("--average", action="store_true",
                        help="plot the mean of each row of particles (error bars: spread) "
                             "instead of every particle")
    parser.add_argument("--steady", action="store_true",
                        help="also draw the steady analytic profile (dashed)")
    parser.add_argument("--initial", action="store_true",
                        help="include the t = 0 snapshot (fluid at rest)")
    parser.add_argument("--title", help="plot title (default: case, dimension and dx/L)")
    parser.add_argument("--dpi", type=int, default=200,
                        help="resolution of raster output (default 200)")
    args = parser.parse_args(argv)
    if args.dpi <= 0:
        parser.error("--dpi must be positive")

    try:
        files = collect(args.inputs)
        series = []
        for path in files:
            snap = sph_snapshot.load(path)
            case = channel_parameters(snap["input"], args.case)["case"]
            if case not in ("poiseuille", "couette"):
                raise ValueError(f"{path}: the input has analytic = '{case}'; "
                                 "give --case poiseuille or --case couette")
            # (par["dx"]: the file's spacing, sph_snapshot.spacing, as the table's)
            time, par, error, nfluid = snapshot_error(snap, case)
            if nfluid == 0:
                raise ValueError(f"{path}: no fluid particles")
            if time == 0 and not args.initial:
                continue
            series.append((time, path, snap, par, case, error))
    except (OSError, KeyError, ValueError) as problem:
        print(f"sph_plot_profiles: {problem}", file=sys.stderr)
        return 1
    if not series:
        print("sph_plot_profiles: no snapshot with t > 0 to plot (--initial includes t = 0)",
              file=sys.stderr)
        return 1
    series.sort(key=lambda s: s[0])
    par, case = series[-1][3], series[-1][4]
    if len({(round(s[3]["width"], 15), s[4]) for s in series}) > 1:
        print("sph_plot_profiles: warning: the snapshots come from different set-ups; "
              "the title describes the last one", file=sys.stderr)
    elif len({round(s[3]["dx"], 15) for s in series}) > 1:
        # (a run remeshed on its way, whose files carry their own spacing: one set-up)
        print("sph_plot_profiles: note: the snapshots' spacings differ (a remeshed run?); "
              "the title gives the last one's", file=sys.stderr)

    umax = max(np.abs(s[2]["velocity"][s[2]["kind"] == 0, s[3]["flow"]]).max() for s in series)
    steady_max = np.abs(exact_profile(par, case, np.linspace(0, par["width"], 201), np.inf)).max()
    vscale, vunit = si_scale(max(umax, steady_max), "m/s")
    lscale, lunit = si_scale(par["width"], "m")

    plt.rcParams.update({"font.size": 10, "axes.linewidth": 0.8})
    fig, ax = plt.subplots(figsize=(6.4, 4.6), dpi=args.dpi)
    cmap = plt.get_cmap("tab10")
    fine = np.linspace(0.0, par["width"], 400)
    for i, (time, path, snap, spar, scase, error) in enumerate(series):
        colour = cmap(i % 10)
        fluid = snap["kind"] == 0
        y = wall_distance(spar, snap["position"][fluid])
        u = snap["velocity"][fluid, spar["flow"]]
        if args.average:
            ym, um, us = level_row_means(y, u, snap["level"][fluid], spar["dx"])
            ax.errorbar(ym / lscale, um / vscale, yerr=us / vscale, fmt="o", ms=3.5, mfc="white",
                        mec=colour, ecolor=colour, mew=1.0, elinewidth=0.8, capsize=1.5, zorder=3)
        else:
            ax.plot(y / lscale, u / vscale, "o", ms=3.0, mfc="none", mec=colour, mew=0.6,
                    alpha=0.85, zorder=3)
        ax.plot(fine / lscale, exact_profile(spar, scase, fine, time) / vscale, "-", color=colour,
                lw=1.1, zorder=2,
                label=f"t = {time:.4g} s   (L2 error {percent(error)})")
    if args.steady:
        ax.plot(fine / lscale, exact_profile(par, case, fine, np.inf) / vscale, "--", color="0.35",
                lw=1.0, zorder=1, label="steady state")
    handles, labels = ax.get_legend_handles_labels()
    handles += [Line2D([], [], ls="", marker="o", ms=4, mfc="none" if not args.average else "white",
                       mec="0.2", mew=0.8),
                Line2D([], [], color="0.2", lw=1.3)]
    labels += ["SPH, " + ("row means ± spread" if args.average else "fluid particles"),
               "analytic solution"]
    ax.legend(handles, labels, fontsize=8, frameon=True, framealpha=0.9,
              loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    ax.set_xlim(0.0, par["width"] / lscale)
    # (the channel's own axes: walls on the x faces give u_y against x)
    names = "xyz"
    across, along = names[par["axis"]], names[par["flow"]]
    ax.set_xlabel(f"distance from the resting wall, ${across}$ [{lunit}]" if par["sign"] < 0
                  else f"${across} - {across}_0$ [{lunit}]")
    ax.set_ylabel(f"$u_{along}$ [{vunit}]")
    ax.axhline(0.0, color="0.6", lw=0.6, zorder=0)
    n_per_width = par["width"] / par["dx"]
    title = args.title or (f"{case.capitalize()} flow ({int(series[-1][2]['dimension'])}D), "
                           f"dx/L = {par['dx'] / par['width']:.4g} (L/{n_per_width:.0f}), "
                           f"L = {par['width'] / lscale:.4g} {lunit}")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.25, lw=0.6)
    ax.tick_params(direction="in", top=True, right=True)
    fig.tight_layout()
    try:
        fig.savefig(args.output, dpi=args.dpi, bbox_inches="tight")
    except (OSError, ValueError) as problem:
        print(f"sph_plot_profiles: cannot write {args.output}: {problem}", file=sys.stderr)
        return 1
    finally:
        plt.close(fig)
    print(f"wrote {args.output} ({len(series)} time(s), {case})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
