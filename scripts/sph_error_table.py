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
(the same region of a uniform run, for comparison), --outside to the others; y is the
coordinate across the channel (the axis whose faces are walls), the flow runs along the body
force or the moving wall, as the program takes them. A channel without that drive (--case
poiseuille without a body force) has a fluid at rest for reference and is refused. The dx/L
column is the file's spacing (its attribute dx, else the input's &domain dx: the input keeps
the spacing a remeshed run began with) over the channel's width.
"""
import argparse
import os
import sys

import numpy as np

try:
    import f90nml
except ImportError as missing:  # pragma: no cover - a message, not a traceback
    sys.exit(f"sph_error_table: {missing.name} is missing; run scripts/install-deps "
             "and use .venv/bin/python")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import sph_analytic  # noqa: E402
import sph_snapshot  # noqa: E402


def channel_parameters(text, case=None):
    """The channel of the resolved namelist text, as the program finds it (&run analytic):
    the wall-normal axis (walls on both of its faces), the flow axis (along the body force,
    or the moving wall's velocity), and the distance from the resting wall, y = sign *
    (x[axis] - y0), with the moving wall (Couette) at y = width. Also the viscosity, the
    drive along the flow (body force, moving wall's speed) and the input's dx (a file's own
    spacing is sph_snapshot.spacing's, which snapshot_error puts here). A set-up that is no
    such channel gets axis None (its case has no analytic solution here). case overrides
    the input's analytic key (--case), which decides the drive: a moving wall's velocity
    (Couette) or the body force."""
    nml = f90nml.reads(text)
    domain, fluid, run = nml["domain"], nml["fluid"], nml["run"]
    dim = int(domain.get("dimension", 2))
    lo = np.asarray(domain["box_lo"], dtype=float)
    hi = np.asarray(domain["box_hi"], dtype=float)
    wall = np.asarray(domain["wall_velocity"], dtype=float).reshape(6, 3)
    force = np.zeros(3)
    given = np.asarray(fluid["body_force"], dtype=float).ravel()
    force[:len(given)] = given
    boundary = domain.get("boundary", ["periodic"] * 6)
    boundary = [boundary] if isinstance(boundary, str) else list(boundary)
    boundary = [str(b).strip().lower() for b in boundary] + ["periodic"] * 6
    walled = [a for a in range(dim) if boundary[2 * a] == "wall" and boundary[2 * a + 1] == "wall"]
    axis = walled[0] if len(walled) == 1 else None
    case = case or str(run.get("analytic", "none")).strip().lower()
    par = {"case": case, "axis": axis, "flow": 0, "sign": 1.0, "y0": 0.0, "width": 0.0,
           "nu": float(fluid["nu"]), "force": 0.0, "wall_speed": 0.0,
           "dx": float(domain["dx"])}
    if axis is None:
        return par
    par["y0"], par["width"] = lo[axis], hi[axis] - lo[axis]
    moving = [f for f in (2 * axis, 2 * axis + 1) if np.any(wall[f] != 0.0)]
    drive = wall[moving[0]] if (case == "couette" and moving) else force
    along = np.flatnonzero(drive != 0.0)
    par["flow"] = int(along[0]) if len(along) else (1 if axis == 0 else 0)
    par["force"] = float(force[par["flow"]])
    if case == "couette" and moving:
        par["wall_speed"] = float(wall[moving[0], par["flow"]])
        if moving[0] == 2 * axis:
            # the lower wall moves: measured from the upper, resting one
            par["sign"], par["y0"] = -1.0, hi[axis]
    return par


def wall_distance(par, positions):
    """The distance of each position from the channel's resting wall (channel_parameters)."""
    return par["sign"] * (positions[:, par["axis"]] - par["y0"])


def no_drive(case):
    """Why a channel without the drive of `case` has no relative error (the program's words)."""
    if case == "couette":
        return ("the couette reference needs a moving wall (&domain wall_velocity) or a body "
                "force along the flow (&fluid body_force); with neither the fluid stays at "
                "rest: no relative error (another --case?)")
    return ("the poiseuille reference needs a body force along the flow (&fluid body_force); "
            "without one the fluid stays at rest: no relative error (a moving wall: "
            "--case couette)")


def snapshot_error(path, case=None, steady=False, level=None, band=None, outside=None):
    """(time, channel_parameters with the file's spacing, relative L2 error or NaN where the
    reference is round-off, number of particles summed) of a snapshot file, or of a
    sph_snapshot.load() result. Raises ValueError (sph_snapshot.SnapshotError for a file that
    is no complete snapshot) with a message naming the file."""
    # (the loader's checks: a file without write_complete was used silently, a directory or
    # another tool's file gave h5py's messages)
    snap = path if isinstance(path, dict) else sph_snapshot.load(path)
    path = snap["path"]
    time = float(snap["time"])
    kind, pos, vel, levels = snap["kind"], snap["position"], snap["velocity"], snap["level"]
    par = channel_parameters(snap["attrs"].get("input", ""), case)
    # (after an in-run remesh the stored input keeps the spacing the run began with)
    par["dx"] = sph_snapshot.spacing(snap)
    case = par["case"]
    if par["axis"] is None:
        raise ValueError(f"{path}: not a channel (walls on both faces of one axis, the "
                         "others periodic): no analytic profile")
    fluid = kind == 0
    if level is not None:
        fluid &= levels == level
    normal = pos[:, par["axis"]]
    if band is not None:
        fluid &= (normal >= band[0]) & (normal < band[1])
    if outside is not None:
        fluid &= (normal < outside[0]) | (normal >= outside[1])
    if not fluid.any():
        # (an empty selection has no error: it printed 0 % before)
        raise ValueError(f"{path}: no fluid particle in the selection (--level, --band, "
                         "--outside)")
    y = wall_distance(par, pos[fluid])
    t = np.inf if steady else time
    exact_x = sph_analytic.channel(case, y, t, par)
    if exact_x is None:
        raise ValueError(f"{path}: no analytic case (input analytic='{case}'); give --case")
    # as the program (sph_reference reference_resolved): below 1e-8 of the channel's peak
    # speed the series is round-off (1.3e14 % for Couette at nu t / L^2 = 1e-6): no figure
    peak = max(abs(par["wall_speed"]), abs(par["force"]) * par["width"] ** 2 / (8 * par["nu"])
               if par["nu"] > 0 else 0.0)
    if not peak > 0:
        # (a reference of a fluid at rest is 0: the velocities' norm was printed as a
        # percentage, 0.0181 % for --case poiseuille on a Couette flow; the program refuses
        # such an input alike, sph_domain_input)
        raise ValueError(f"{path}: {no_drive(case)}")
    exact = np.zeros_like(vel[fluid])
    exact[:, par["flow"]] = exact_x
    norm = np.linalg.norm(exact)
    err = np.linalg.norm(vel[fluid] - exact)
    if norm / np.sqrt(max(int(fluid.sum()), 1)) < 1e-8 * peak:
        return time, par, float("nan"), int(fluid.sum())
    return time, par, err / norm, int(fluid.sum())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("snapshots", nargs="+", help="HDF5 snapshot files")
    parser.add_argument("--case", choices=["poiseuille", "couette"],
                        help="analytic solution (default: the file's &run analytic)")
    parser.add_argument("--steady", action="store_true",
                        help="compare with the steady profile instead of the transient one")
    parser.add_argument("--level", type=int, help="only the real particles of this level")
    parser.add_argument("--band", type=float, nargs=2, metavar=("YLO", "YHI"),
                        help="only the particles with YLO <= y < YHI (m), y the coordinate "
                             "across the channel")
    parser.add_argument("--outside", type=float, nargs=2, metavar=("YLO", "YHI"),
                        help="only the particles with y < YLO or y >= YHI (m)")
    args = parser.parse_args(argv)
    print(f"{'file':<48} {'t [s]':>10} {'dx/L':>8} {'fluid':>7} {'rel. L2 error':>14}")
    status = 0
    for path in args.snapshots:
        try:
            time, par, err, n = snapshot_error(path, args.case, args.steady, args.level,
                                               args.band, args.outside)
        except (OSError, KeyError, ValueError) as problem:
            # (the others are still reported: a glob's first bad file hid the rest)
            text = str(problem.args[0]) if isinstance(problem, KeyError) else str(problem)
            if not text.startswith(path):
                text = f"{path}: {text}"
            print(f"sph_error_table: {text}", file=sys.stderr)
            status = 1
            continue
        if time == 0 and not args.steady:
            continue
        # the spacing of the level asked for (level L: dx / 2^L)
        spacing = par["dx"] / 2 ** (args.level or 0)
        figure = f"{'n/a':>14}" if np.isnan(err) else f"{100 * err:13.4f}%"
        print(f"{path:<48} {time:10.4g} {spacing / par['width']:8.4f} {n:7d} {figure}")
    return status


if __name__ == "__main__":
    sys.exit(main())
