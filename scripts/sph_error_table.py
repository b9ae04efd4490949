#!/usr/bin/env python3
"""Print the relative L2 velocity error of Couette/Poiseuille snapshots against the analytic
solution, computed from the HDF5 files alone (positions, velocities, kinds and the resolved
input stored in each file).

  scripts/sph_error_table.py output/poiseuille/*.h5
  scripts/sph_error_table.py --steady output/poiseuille/poiseuille_007575.h5
  scripts/sph_error_table.py --level 1 output/poiseuille_multires/*.h5
  scripts/sph_error_table.py --band 0.25e-3 0.75e-3 output/poiseuille/*.h5
  scripts/sph_error_table.py --outside 0.25e-3 0.75e-3 output/poiseuille/*.h5

The error is ||v - v_exact|| / ||v_exact|| over all real fluid particles (every velocity
component counts; virtual particles, kind 2, are left out). The case comes from the file's
`analytic` input key, or --case. --level restricts the sums to the real particles of one
resolution level (a multi-resolution run), --band to those with band[0] <= y < band[1]
(the same region of a uniform run, for comparison), --outside to the others.
"""
import argparse
import sys

import numpy as np

try:
    import h5py
    import f90nml
except ImportError as missing:  # pragma: no cover - a message, not a traceback
    sys.exit(f"sph_error_table: {missing.name} is missing; run scripts/install-deps "
             "and use .venv/bin/python")

import sph_analytic


def channel_parameters(text):
    """Width, viscosity, body force and upper-wall speed from the resolved namelist text."""
    nml = f90nml.reads(text)
    domain, fluid, run = nml["domain"], nml["fluid"], nml["run"]
    lo = np.asarray(domain["box_lo"], dtype=float)
    hi = np.asarray(domain["box_hi"], dtype=float)
    wall = np.asarray(domain["wall_velocity"], dtype=float).reshape(6, 3)
    return {
        "case": str(run.get("analytic", "none")).strip().lower(),
        "y0": lo[1],
        "width": hi[1] - lo[1],
        "nu": float(fluid["nu"]),
        "force": float(np.asarray(fluid["body_force"], dtype=float)[0]),
        "wall_speed": wall[3, 0],
        "dx": float(domain["dx"]),
    }


def snapshot_error(path, case=None, steady=False, level=None, band=None, outside=None):
    with h5py.File(path, "r") as f:
        time = float(f.attrs["time"])
        text = f.attrs["input"]
        text = text.decode() if isinstance(text, bytes) else str(text)
        parts = f["particles"]
        kind = parts["kind"][:]
        pos = parts["position"][:]
        vel = parts["velocity"][:]
        levels = parts["level"][:] if "level" in parts else np.zeros_like(kind)
    par = channel_parameters(text)
    case = case or par["case"]
    fluid = kind == 0
    if level is not None:
        fluid &= levels == level
    if band is not None:
        fluid &= (pos[:, 1] >= band[0]) & (pos[:, 1] < band[1])
    if outside is not None:
        fluid &= (pos[:, 1] < outside[0]) | (pos[:, 1] >= outside[1])
    if not fluid.any():
        # (an empty selection has no error: it printed 0 % before)
        raise ValueError("no fluid particle in the selection (--level, --band, --outside)")
    y = pos[fluid, 1] - par["y0"]
    t = np.inf if steady else time
    if case == "poiseuille":
        exact_x = sph_analytic.poiseuille(y, t, par["force"], par["width"], par["nu"])
    elif case == "couette":
        exact_x = sph_analytic.couette(y, t, par["wall_speed"], par["width"], par["nu"])
    else:
        raise ValueError(f"{path}: no analytic case (input analytic='{case}'); give --case")
    exact = np.zeros_like(vel[fluid])
    exact[:, 0] = exact_x
    norm = np.linalg.norm(exact)
    err = np.linalg.norm(vel[fluid] - exact)
    return time, par, (err / norm if norm > 0 else err), int(fluid.sum())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("snapshots", nargs="+", help="HDF5 snapshot files")
    parser.add_argument("--case", choices=["poiseuille", "couette"],
                        help="analytic solution (default: the file's &run analytic)")
    parser.add_argument("--steady", action="store_true",
                        help="compare with the steady profile instead of the transient one")
    parser.add_argument("--level", type=int, help="only the real particles of this level")
    parser.add_argument("--band", type=float, nargs=2, metavar=("YLO", "YHI"),
                        help="only the particles with YLO <= y < YHI (m)")
    parser.add_argument("--outside", type=float, nargs=2, metavar=("YLO", "YHI"),
                        help="only the particles with y < YLO or y >= YHI (m)")
    args = parser.parse_args(argv)
    print(f"{'file':<48} {'t [s]':>10} {'dx/L':>8} {'fluid':>7} {'rel. L2 error':>14}")
    for path in args.snapshots:
        try:
            time, par, err, n = snapshot_error(path, args.case, args.steady, args.level,
                                               args.band, args.outside)
        except (OSError, KeyError, ValueError) as problem:
            print(f"sph_error_table: {path}: {problem}", file=sys.stderr)
            return 1
        if time == 0 and not args.steady:
            continue
        # the spacing of the level asked for (level L: dx / 2^L)
        spacing = par["dx"] / 2 ** (args.level or 0)
        print(f"{path:<48} {time:10.4g} {spacing / par['width']:8.4f} {n:7d} {100 * err:13.4f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
