#!/usr/bin/env python3
"""Plot one particle field of a snapshot, coloured on the particles (x-y plane).

  scripts/sph_plot_field.py output/poiseuille/poiseuille_007575.h5 --field velocity_x -o u.png
  scripts/sph_plot_field.py FILE.h5 --field rank --kinds fluid,wall -o ranks.png
  scripts/sph_plot_field.py FILE3D.h5 --field pressure --z 0.5e-3 -o p.png

Fields: density, pressure, mass, smoothing_length, energy, id, kind, level, rank,
velocity_magnitude (or velocity), velocity_x/_y/_z, position_x/_y/_z. For 3D snapshots
the particles of the slice |z - z0| < dx/2 are shown (--z z0 in m; default: the particle
layer nearest the middle of the box). The dashed rectangle is the fluid box of the input.
"""
import argparse
import os
import sys

import numpy as np

try:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.patches import Rectangle
except ImportError as missing:  # pragma: no cover - a message, not a traceback
    sys.exit(f"sph_plot_field: {missing.name} is missing; run scripts/install-deps "
             "and use .venv/bin/python")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import sph_snapshot  # noqa: E402

KIND_NAMES = sph_snapshot.KIND_CODES            # {"fluid": 0, "wall": 1, "virtual": 2}
UNITS = {"position": "m", "velocity": "m/s", "density": "kg/m³", "pressure": "Pa",
         "mass": "kg", "smoothing_length": "m", "energy": "J/kg"}
DISCRETE = ("kind", "level", "rank")
KIND_COLOURS = ("#1f77b4", "#7f7f7f", "#d62728")  # fluid blue, wall grey, virtual red


def field_names(snap):
    names = ["velocity_magnitude"]
    names += [f"{v}_{c}" for v in ("velocity", "position") for c in "xyz"]
    names += [k for k, v in snap.items()
              if isinstance(v, np.ndarray) and v.ndim == 1 and k not in names]
    return names


def field_values(snap, name):
    """(values, unit) of a field; KeyError naming the field and the choices if unknown."""
    if name in ("velocity_magnitude", "speed", "velocity", "|velocity|"):
        return np.linalg.norm(snap["velocity"], axis=1), "m/s"
    for vector in ("velocity", "position"):
        for axis, label in enumerate("xyz"):
            if name == f"{vector}_{label}":
                return snap[vector][:, axis], UNITS[vector]
    value = snap.get(name)
    if isinstance(value, np.ndarray) and value.ndim == 1 and name != "attrs":
        return value, UNITS.get(name, "")
    raise KeyError(f"unknown field '{name}'; choose one of: {', '.join(field_names(snap))}")


def parse_kinds(text):
    wanted = []
    for word in text.split(","):
        word = word.strip().lower()
        if not word:
            continue
        if word == "all":
            wanted.extend(KIND_NAMES.values())
        elif word in KIND_NAMES:
            wanted.append(KIND_NAMES[word])
        else:
            raise ValueError(f"unknown kind '{word}' in --kinds; kinds are fluid, wall, virtual "
                             "(or all)")
    if not wanted:
        raise ValueError("--kinds selects nothing; kinds are fluid, wall, virtual (or all)")
    return sorted(set(wanted))


def main(argv=None):
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Fields: " + __doc__.split("Fields: ")[1].split("\n\n")[0].replace("\n", " "))
    parser.add_argument("snapshot", metavar="FILE.h5", help="HDF5 snapshot file")
    parser.add_argument("--field", "-f", default="velocity_magnitude",
                        help="field to colour by (default velocity_magnitude)")
    parser.add_argument("--kinds", default="fluid,wall",
                        help="comma-separated particle kinds to show: fluid, wall, virtual, all "
                             "(default fluid,wall)")
    parser.add_argument("--z", type=float, metavar="Z0",
                        help="3D: slice position in m (default: the particle layer nearest "
                             "the middle of the box); the slice is |z - Z0| < dx/2")
    parser.add_argument("--output", "-o", required=True, metavar="FILE.png", help="image to write")
    parser.add_argument("--cmap", help="matplotlib colour map (default: viridis, or RdBu_r "
                                       "centred on 0 for fields of both signs)")
    parser.add_argument("--vmin", type=float,
                        help="lower end of the colour scale, in the field's SI unit")
    parser.add_argument("--vmax", type=float,
                        help="upper end of the colour scale, in the field's SI unit")
    parser.add_argument("--title", help="plot title")
    parser.add_argument("--dpi", type=int, default=200, help="resolution (default 200)")
    args = parser.parse_args(argv)
    if args.dpi <= 0:
        parser.error("--dpi must be positive")
    if args.vmin is not None and args.vmax is not None and not args.vmin < args.vmax:
        parser.error("--vmin must be below --vmax")
    try:
        wanted = parse_kinds(args.kinds)
        snap = sph_snapshot.load(args.snapshot)
        values, unit = field_values(snap, args.field)
        if args.cmap is not None and args.cmap not in plt.colormaps():
            raise ValueError(f"unknown colour map '{args.cmap}'")
    except KeyError as problem:
        print(f"sph_plot_field: {problem.args[0]}", file=sys.stderr)
        return 1
    except (OSError, ValueError) as problem:
        print(f"sph_plot_field: {problem}", file=sys.stderr)
        return 1
    geo = sph_snapshot.geometry(snap)
    dx = geo["dx"]
    pos = snap["position"]
    keep = np.isin(snap["kind"], wanted)
    where = ""
    if geo["dimension"] == 3:
        if args.z is not None:
            z0 = args.z
        else:
            mid = 0.5 * (geo["box_lo"][2] + geo["box_hi"][2])
            zs = pos[keep, 2]
            z0 = zs[np.argmin(np.abs(zs - mid))] if len(zs) else mid
        keep &= np.abs(pos[:, 2] - z0) < 0.5 * dx
        zf, zu = sph_snapshot.si_scale(max(abs(z0), dx), "m")
        where = f"|z - {z0 / zf:.4g} {zu}| < dx/2"
    if not keep.any():
        print(f"sph_plot_field: no particles to show in {args.snapshot} (kinds {args.kinds}"
              + (f", slice {where}" if where else "") + ")", file=sys.stderr)
        return 1

    x, y, v = pos[keep, 0], pos[keep, 1], values[keep]
    lo, hi = geo["box_lo"], geo["box_hi"]
    xmin, xmax = min(x.min(), lo[0]) - dx, max(x.max(), hi[0]) + dx
    ymin, ymax = min(y.min(), lo[1]) - dx, max(y.max(), hi[1]) + dx
    lscale, lunit = sph_snapshot.si_scale(max(xmax - xmin, ymax - ymin), "m")
    vscale = 1.0
    base = args.field.split("_")[0]
    if unit in ("m", "m/s") and base in ("velocity", "position", "smoothing", "speed"):
        vscale, unit = sph_snapshot.si_scale(np.abs(v).max(), unit)
    v = v / vscale

    plt.rcParams.update({"font.size": 10, "axes.linewidth": 0.8})
    aspect = (ymax - ymin) / (xmax - xmin)
    width = 6.0
    ax_w = width - 1.9                              # room for labels and the colour bar
    height = float(np.clip(ax_w * aspect + 1.1, 2.5, 9.0))
    fig, ax = plt.subplots(figsize=(width, height), dpi=args.dpi)
    ax.set_xlim(xmin / lscale, xmax / lscale)
    ax.set_ylim(ymin / lscale, ymax / lscale)
    ax.set_aspect("equal")

    discrete = args.field in DISCRETE and np.issubdtype(values.dtype, np.integer)
    if discrete:
        codes = np.unique(v).astype(int)
        levels = np.arange(codes.min(), codes.max() + 2) - 0.5
        count = len(levels) - 1
        if args.field == "kind":
            colours = [KIND_COLOURS[c] if 0 <= c < 3 else "k" for c in range(codes.min(), codes.max() + 1)]
        else:
            base_map = plt.get_cmap(args.cmap or ("tab10" if count <= 10 else "tab20" if count <= 20 else "turbo"))
            colours = base_map(np.linspace(0, 1, count)) if count > 20 else \
                [base_map(i % base_map.N) for i in range(count)]
        cmap = ListedColormap(colours)
        norm = BoundaryNorm(levels, cmap.N)
    else:
        # (the limits are SI, as the field in the file; the colour bar's unit is picked from
        # the data, so they are scaled with it: they were taken in that unit)
        vmin = args.vmin / vscale if args.vmin is not None else float(v.min())
        vmax = args.vmax / vscale if args.vmax is not None else float(v.max())
        signed = args.vmin is None and args.vmax is None and vmin < 0 < vmax
        if signed:
            vmax = max(-vmin, vmax)
            vmin = -vmax
        if vmin == vmax:
            pad = abs(vmin) * 1e-6 or 1.0
            vmin, vmax = vmin - pad, vmax + pad
        cmap = plt.get_cmap(args.cmap or ("RdBu_r" if signed else "viridis"))
        norm = matplotlib.colors.Normalize(vmin=vmin, vmax=vmax)

    # markers about one particle spacing across
    fig.canvas.draw()
    bbox = ax.get_window_extent()
    points_per_m = bbox.width / (xmax - xmin) * 72.0 / fig.dpi
    size = float(np.clip(0.85 * dx * points_per_m, 0.5, 40.0)) ** 2
    order = np.argsort(snap["kind"][keep], kind="stable")[::-1]   # fluid drawn on top
    sc = ax.scatter(x[order] / lscale, y[order] / lscale, c=v[order], s=size, cmap=cmap,
                    norm=norm, linewidths=0, rasterized=len(x) > 20000)
    ax.add_patch(Rectangle((lo[0] / lscale, lo[1] / lscale), (hi[0] - lo[0]) / lscale,
                           (hi[1] - lo[1]) / lscale, fill=False, ls="--", lw=0.7, ec="0.3",
                           zorder=3))
    label = args.field + (f" [{unit}]" if unit else "")
    bar = fig.colorbar(sc, ax=ax, label=label, fraction=0.05, pad=0.03)
    if discrete:
        ticks = np.arange(codes.min(), codes.max() + 1)
        if len(ticks) > 20:
            ticks = ticks[:: int(np.ceil(len(ticks) / 20))]
        bar.set_ticks(ticks)
        if args.field == "kind":
            names = {c: n for n, c in KIND_NAMES.items()}
            bar.set_ticklabels([names.get(int(t), str(t)) for t in ticks])
        bar.ax.minorticks_off()
    ax.set_xlabel(f"$x$ [{lunit}]")
    ax.set_ylabel(f"$y$ [{lunit}]")
    ax.tick_params(direction="in", top=True, right=True)
    case = os.path.basename(args.snapshot).rsplit("_", 1)[0]
    title = args.title or (f"{case}: {args.field} at t = {snap['time']:.4g} s"
                           + (f", slice {where}" if where else "")
                           + f"\n{int(keep.sum())} particles ({args.kinds}), "
                              f"dx = {dx / sph_snapshot.si_scale(dx, 'm')[0]:.4g} "
                              f"{sph_snapshot.si_scale(dx, 'm')[1]}")
    ax.set_title(title, fontsize=9.5)
    fig.tight_layout()
    try:
        fig.savefig(args.output, dpi=args.dpi, bbox_inches="tight")
    except (OSError, ValueError) as problem:
        print(f"sph_plot_field: cannot write {args.output}: {problem}", file=sys.stderr)
        return 1
    finally:
        plt.close(fig)
    print(f"wrote {args.output} ({args.field}, {int(keep.sum())} particles)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
