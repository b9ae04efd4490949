#!/usr/bin/env python3
"""Write the initial particles sphremesh would make for a namelist to an HDF5 file.

    make_initial_particles.py INPUT.nml -o particles.h5 [--force]

An existing particles.h5 is kept (the script stops with a message) unless --force.

The file holds the fluid lattice (spacing dx, first site at box_lo + dx/2, row-major in
x, then y, then z) and, for wall_model = 'morris', the wall particles: every site of the
lattice extended by the wall layers that lies behind a wall face. Ids are those the
program assigns (fluid 1..N in lattice order, walls N + 1 + their index in the extended
lattice). A run with `&domain initial_particles = 'particles.h5'` and the same input
starts from exactly these particles and repeats the lattice run bit for bit (builds
without floating-point contraction, e.g. Debug). Start from this file to build your own:
move, drop or add particles and set velocities with numpy (doc/output.md, "Starting from
your own particles").

Written: /particles/position, kind, id, density, root attribute dimension. Left out, so
that the program makes them exactly as for the lattice: velocity (fluid at rest, walls
move with their wall), mass (the lattice's, doc/physics.md), and the wall geometry (solid,
wall_normal, wall_distance, from the solids). &body solids and the 'repulsive' wall models are not
handled (the script stops with a message).
"""
import argparse
import math
import os
import sys

import numpy as np

try:
    import f90nml
    import h5py
except ImportError as err:  # pragma: no cover - the venv has them
    sys.exit(f"make_initial_particles: {err.name} is missing (run scripts/install-deps)")

FACES = ["xlo", "xhi", "ylo", "yhi", "zlo", "zhi"]
SUPPORT = {"cubic": 2.0, "quintic": 3.0, "wendland_c2": 2.0}
DEFAULT_H = {"cubic": 1.3, "quintic": 1.0, "wendland_c2": 1.5}


def _group(nml, name):
    return nml[name] if name in nml else {}


def _array(group, key, default, n):
    """A namelist array with the program's default for every element not given; elements
    given from an index on (`boundary(3:4) = 'wall', 'wall'`) go there, not to the first
    ones (they did: the walls went on the x faces, and the program refused the file)."""
    values = [default] * n
    given = group.get(key)
    if given is None:
        return values
    if not isinstance(given, list):
        given = [given]
    start = 1
    first = (getattr(group, "start_index", None) or {}).get(key)
    if first and first[0] is not None:
        start = first[0]
    for k, value in enumerate(given):
        if value is not None and 0 <= start - 1 + k < n:
            values[start - 1 + k] = value
    return values


def read_case(path):
    """The keys the lattice depends on, with the program's defaults."""
    try:
        nml = f90nml.read(path)
    except (OSError, ValueError, StopIteration) as problem:
        raise SystemExit(f"make_initial_particles: cannot read the namelist '{path}': {problem}")
    if len(nml) == 0:
        raise SystemExit(f"make_initial_particles: '{path}' holds no namelist group: not an "
                         "input")
    if "body" in nml:
        raise SystemExit(f"make_initial_particles: '{path}' has &body solids; "
                         "only box walls are handled")
    # (sphremesh refuses initial particles with refinement regions: a uniform file for such an
    # input was written, then refused by the run)
    if "region" in nml:
        raise SystemExit(f"make_initial_particles: '{path}' has &region groups; initial "
                         "particles from a file are for one resolution level (sphremesh "
                         "refuses them with &region)")
    domain, fluid, numerics = (_group(nml, g) for g in ("domain", "fluid", "numerics"))
    case = {
        "dimension": int(domain.get("dimension", 2)),
        "box_lo": [float(v) for v in _array(domain, "box_lo", 0.0, 3)],
        "box_hi": [float(v) for v in _array(domain, "box_hi", 1.0, 3)],
        "boundary": [str(v).lower() for v in _array(domain, "boundary", "periodic", 6)],
        "dx": float(domain.get("dx", 0.05)),
        "rho0": float(fluid.get("rho0", 1000.0)),
        "kernel": str(numerics.get("kernel", "cubic")).lower(),
        "h_factor": float(numerics.get("h_factor", 0.0)),
        "wall_model": str(numerics.get("wall_model", "morris")).lower(),
    }
    if case["wall_model"] in ("repulsive", "repulsive_mirror"):
        raise SystemExit("make_initial_particles: wall_model "
                         f"'{case['wall_model']}' is not handled (use 'morris' or 'mirror')")
    return case


def make_particles(case):
    """Positions (N, 3), kinds and ids, in the order and with the ids of the program."""
    dim, dx = case["dimension"], case["dx"]
    lo, hi = case["box_lo"], case["box_hi"]
    n_inside = [1, 1, 1]
    for axis in range(dim):
        n_inside[axis] = int(round((hi[axis] - lo[axis]) / dx))
    n_fluid = n_inside[0] * n_inside[1] * n_inside[2]

    def sites(first, last):
        """Lattice positions of index ranges first..last (1-based, inclusive), x fastest."""
        axes = []
        for axis in range(3):
            idx = np.arange(first[axis], last[axis] + 1, dtype=np.float64)
            axes.append(lo[axis] + (idx - 0.5) * dx if axis < dim else np.zeros(1))
        z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
        return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)

    position = sites([1, 1, 1], n_inside)
    ids = np.arange(1, n_fluid + 1, dtype=np.int64)
    kind = np.zeros(n_fluid, dtype=np.int32)
    if case["wall_model"] == "morris":
        h = (case["h_factor"] if case["h_factor"] > 0 else DEFAULT_H[case["kernel"]]) * dx
        layers = math.ceil(SUPPORT[case["kernel"]] * h / dx - 1.0e-9)
        first, last = [1, 1, 1], list(n_inside)
        for axis in range(dim):
            if case["boundary"][2 * axis] == "wall":
                first[axis], last[axis] = 1 - layers, n_inside[axis] + layers
        extended = sites(first, last)
        behind = np.zeros(len(extended), dtype=bool)
        for face in range(2 * dim):
            if case["boundary"][face] != "wall":
                continue
            axis = face // 2
            if face % 2 == 0:
                behind |= extended[:, axis] < lo[axis]
            else:
                behind |= extended[:, axis] > hi[axis]
        wall_ids = n_fluid + 1 + np.flatnonzero(behind).astype(np.int64)
        position = np.concatenate([position, extended[behind]])
        ids = np.concatenate([ids, wall_ids])
        kind = np.concatenate([kind, np.ones(len(wall_ids), dtype=np.int32)])
    return position, kind, ids


def main(argv=None):
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Then run with &domain initial_particles = 'FILE' in the same input.")
    parser.add_argument("input", help="the namelist (sphremesh input file)")
    parser.add_argument("-o", "--output", required=True,
                        help="HDF5 file to write (a new file, unless --force)")
    parser.add_argument("--force", action="store_true",
                        help="replace OUTPUT when it exists")
    args = parser.parse_args(argv)
    # (with --force it ended in an IsADirectoryError traceback; --force replaces files only)
    if os.path.isdir(args.output):
        sys.exit(f"make_initial_particles: '{args.output}' is a directory; give the file to "
                 f"write, e.g. {os.path.join(args.output, 'particles.h5')}")
    # (a user's file is never replaced without --force: -o INPUT.nml overwrote the input)
    if os.path.lexists(args.output) and not args.force:
        sys.exit(f"make_initial_particles: '{args.output}' exists; give another name, or "
                 "--force to replace it")
    folder = os.path.dirname(args.output) or "."
    if not os.path.isdir(folder):
        sys.exit(f"make_initial_particles: the folder '{folder}' of '{args.output}' does not "
                 "exist")
    case = read_case(args.input)
    position, kind, ids = make_particles(case)
    try:
        with h5py.File(args.output, "w") as f:
            f.attrs["dimension"] = np.int32(case["dimension"])
            g = f.create_group("particles")
            g["position"] = position
            g["kind"] = kind
            g["id"] = ids
            g["density"] = np.full(len(ids), case["rho0"])
    except OSError as problem:
        # (a folder without write permission, a full disk: a traceback before)
        sys.exit(f"make_initial_particles: cannot write '{args.output}': {problem}")
    print(f"{args.output}: {len(ids)} particles ({np.count_nonzero(kind == 0)} fluid, "
          f"{np.count_nonzero(kind == 1)} wall), dimension {case['dimension']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
