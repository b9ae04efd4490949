#!/usr/bin/env python3
"""Continuity across the interfaces of a multi-resolution channel run, from its snapshots.

  scripts/sph_interface_profile.py output/poiseuille_multires/poiseuille_multires_007575.h5
  scripts/sph_interface_profile.py --figure doc/multires_profile.png FILE.h5 [UNIFORM.h5 ...]

For every interface (a face of a &region box across the channel, read from the input stored in
the snapshot, or given with --interfaces), the real fluid particles (kind 0, every level) in
the bin of width --bin (default: the coarsest spacing, the file's root attribute dx, else the
stored &domain dx: sph_snapshot.spacing) just below and just above it give a mean
density and a mean streamwise velocity; the script prints both sides and the jump, the
density jump in % of rho0 (the issue's criterion: below 0.2 %). With --figure, the profile of
the streamwise velocity (particles coloured by level) and of the density in bins across the
channel is drawn with the analytic solution (&run analytic), the interfaces marked; further
snapshots given (uniform runs) are drawn as lines of their bin means for comparison.
Exit status 1 when a density jump exceeds --limit (default 0.2 % of rho0).
"""
import argparse
import os
import sys

import numpy as np

try:
    import f90nml
except ImportError as missing:  # pragma: no cover - a message, not a traceback
    sys.exit(f"sph_interface_profile: {missing.name} is missing; run scripts/install-deps "
             "and use .venv/bin/python")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import sph_analytic  # noqa: E402
import sph_snapshot  # noqa: E402
from sph_error_table import channel_parameters  # noqa: E402


def load(path):
    """The columns of a snapshot this script uses, after the loader's checks (a file without
    the write_complete marker was used silently, another tool's file gave "can't locate
    attribute 'time'"); dx: the file's spacing of level 0 (sph_snapshot.spacing). Raises
    sph_snapshot.SnapshotError naming the file."""
    snap = sph_snapshot.load(path)
    return {
        "path": path,
        "time": float(snap["time"]),
        "text": snap["attrs"].get("input", ""),
        "dx": sph_snapshot.spacing(snap),
        "kind": snap["kind"],
        "level": snap["level"],
        "y": snap["position"][:, 1],
        "u": snap["velocity"][:, 0],
        "rho": snap["density"],
    }


def region_interfaces(text, y_lo, y_hi):
    """Faces of the &region boxes across the channel (strictly inside it), sorted."""
    nml = f90nml.reads(text)
    regions = nml.get("region", [])
    if isinstance(regions, f90nml.Namelist):
        regions = [regions]
    faces = set()
    for region in regions:
        if str(region.get("shape", "box")).strip().lower() != "box":
            continue
        for key in ("lo", "hi"):
            value = float(np.asarray(region[key], dtype=float)[1])
            if y_lo < value < y_hi:
                faces.add(value)
    return sorted(faces)


def side_means(data, y0, width):
    real = data["kind"] == 0
    below = real & (data["y"] >= y0 - width) & (data["y"] < y0)
    above = real & (data["y"] >= y0) & (data["y"] < y0 + width)
    out = []
    for mask in (below, above):
        if not mask.any():
            out.append((np.nan, np.nan, 0))
        else:
            out.append((data["rho"][mask].mean(), data["u"][mask].mean(), int(mask.sum())))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("snapshot", help="HDF5 snapshot of the multi-resolution run")
    parser.add_argument("uniform", nargs="*", help="snapshots of uniform runs (figure only)")
    parser.add_argument("--interfaces", type=float, nargs="+", help="interface positions y (m)")
    parser.add_argument("--bin", type=float,
                        help="bin width (m); default the coarsest spacing (the file's "
                             "attribute dx, else its input's &domain dx)")
    parser.add_argument("--limit", type=float, default=0.2,
                        help="largest density jump allowed, in %% of rho0 (default 0.2)")
    parser.add_argument("--figure", help="write the profile figure here (PNG)")
    # (intermixed: uniform snapshots may follow an option, as in "A.h5 --figure f.png B.h5")
    args = parser.parse_intermixed_args(argv)

    try:
        data = load(args.snapshot)
        par = channel_parameters(data["text"])
        # (its bins and faces are along y, its profile u along x, from the lower wall)
        if (par["axis"], par["flow"], par["sign"]) != (1, 0, 1.0):
            raise ValueError("a channel with walls on the y faces, the flow along x and "
                             "(Couette) the upper wall moving is needed")
    except (OSError, KeyError, ValueError) as problem:
        text = str(problem)
        if not isinstance(problem, sph_snapshot.SnapshotError):
            text = f"{args.snapshot}: {text}"
        print(f"sph_interface_profile: {text}", file=sys.stderr)
        return 1
    # the uniform runs' snapshots read now, each with the loader's checks (one missing was
    # reported as a problem of the figure, "the figure 'i2.png': ... nonexist.h5")
    uniform = []
    for path in args.uniform:
        try:
            uniform.append(load(path))
        except (OSError, KeyError, ValueError) as problem:
            print(f"sph_interface_profile: {problem}", file=sys.stderr)
            return 1
    rho0 = float(f90nml.reads(data["text"])["fluid"]["rho0"])
    y_lo, y_hi = par["y0"], par["y0"] + par["width"]
    faces = args.interfaces or region_interfaces(data["text"], y_lo, y_hi)
    # (an empty table with status 0 read as a pass)
    if not faces:
        print(f"sph_interface_profile: {args.snapshot}: no interface between levels across "
              "the channel (&region slabs along y); give --interfaces", file=sys.stderr)
        return 1
    if args.bin is not None and not args.bin > 0:
        print("sph_interface_profile: --bin must be positive (m)", file=sys.stderr)
        return 1
    # (the file's spacing of level 0: the stored input keeps the one the run began with)
    width = args.bin or data["dx"]
    print(f"{args.snapshot}: t = {data['time']:.6g} s, bins of {width:.4g} m")
    print(f"{'interface y [m]':>16} {'rho below':>12} {'rho above':>12} {'jump [% rho0]':>14} "
          f"{'u below':>12} {'u above':>12}")
    worst = 0.0
    empty = []
    for y0 in faces:
        (rb, ub, nb), (ra, ua, na) = side_means(data, y0, width)
        jump = 100.0 * abs(ra - rb) / rho0
        # (an empty bin has no mean: its NaN passed the limit before)
        if nb == 0 or na == 0:
            empty.append(y0)
        else:
            worst = max(worst, jump)
        print(f"{y0:16.6g} {rb:12.6f} {ra:12.6f} {jump:14.5f} {ub:12.5e} {ua:12.5e}")
    if args.figure:
        try:
            draw(args, data, uniform, par, faces, width)
        except (OSError, KeyError, ValueError) as problem:
            print(f"sph_interface_profile: the figure '{args.figure}': {problem}",
                  file=sys.stderr)
            return 1
    if empty:
        print("sph_interface_profile: no real fluid particle within a bin of the interface at "
              f"y = {', '.join(f'{y:.6g}' for y in empty)} m", file=sys.stderr)
        return 1
    if worst > args.limit:
        print(f"sph_interface_profile: density jump {worst:.4f} % of rho0 exceeds "
              f"{args.limit} %", file=sys.stderr)
        return 1
    return 0


def draw(args, data, uniform, par, faces, width):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax_u, ax_rho) = plt.subplots(1, 2, figsize=(10, 4.5))
    y = np.linspace(par["y0"], par["y0"] + par["width"], 400)
    # (only for a case that has one: a zero 'analytic' line was drawn for the others)
    exact = sph_analytic.channel(par["case"], y - par["y0"], data["time"], par)
    if exact is not None:
        ax_u.plot(exact, y, "k-", lw=1, label="analytic")
    real = data["kind"] == 0
    for level, colour in zip(range(4), ["tab:blue", "tab:orange", "tab:green", "tab:red"]):
        mask = real & (data["level"] == level)
        if mask.any():
            ax_u.plot(data["u"][mask], data["y"][mask], ".", ms=2, color=colour,
                      label=f"level {level}")
    edges = np.arange(par["y0"], par["y0"] + par["width"] + width / 2, width)
    centres = 0.5 * (edges[1:] + edges[:-1])
    for other in [data] + uniform:
        sel = other["kind"] == 0
        sums = np.histogram(other["y"][sel], edges, weights=other["rho"][sel])[0]
        counts = np.histogram(other["y"][sel], edges)[0]
        with np.errstate(invalid="ignore"):
            ax_rho.plot(sums / counts, centres, "-" if other is data else "--",
                        label=other["path"].split("/")[-1])
    for y0 in faces:
        for ax in (ax_u, ax_rho):
            ax.axhline(y0, color="grey", lw=0.6, ls=":")
    ax_u.set_xlabel("u [m/s]")
    ax_u.set_ylabel("y [m]")
    ax_u.legend(fontsize=7)
    ax_rho.set_xlabel("mean density in bins [kg/m^3]")
    ax_rho.legend(fontsize=7)
    fig.suptitle(f"t = {data['time']:.4g} s")
    fig.tight_layout()
    fig.savefig(args.figure, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
