#!/usr/bin/env python3
"""Write a variant of an initial-particle file for the poiseuille_short case (regression tests).

    make_bad_particles.py GOOD.h5 KIND OUT.h5

KIND: missing_position, duplicate_id, outside_box, wrong_dimension, integer_positions (the
positions stored as int16), nan_density, huge_density (1e300 kg/m^3), nan_energy,
nan_wall_normal, level_one (every particle at level 1), solid_out_of_range (the walls
labelled solid 7 of 2), solid_swapped (the two walls' labels exchanged), deep_wall (a wall
particle 1 m below its wall), no_walls (the wall particles left out), huge_id (an id of
2^60), float_dimension (the root attribute 2.0), fluid_past_slack (a fluid particle 0.3 h
beyond a wall face) (one defect each), fluid_in_slack (0.1 h beyond: taken), or shuffled
(the same particles, rows in a random order). GOOD.h5 is a file made by
scripts/make_initial_particles.py for a channel with walls on ylo (solid 1) and yhi
(solid 2).
"""
import sys

import h5py
import numpy as np


def main(good, kind, out):
    with h5py.File(good, "r") as f:
        data = {name: f["particles"][name][()] for name in f["particles"]}
        dimension = int(f.attrs["dimension"])
    if kind == "missing_position":
        del data["position"]
    elif kind == "duplicate_id":
        data["id"][5] = data["id"][3]
    elif kind == "outside_box":
        data["position"][7, 0] = -1.0e-3          # a fluid particle left of the box
    elif kind == "shuffled":
        order = np.random.default_rng(12345).permutation(len(data["id"]))
        data = {name: values[order] for name, values in data.items()}
    elif kind == "wrong_dimension":
        dimension = 3
    elif kind == "integer_positions":
        data["position"] = data["position"].astype(np.int16)
    elif kind in ("nan_density", "huge_density"):
        data["density"] = data["density"].astype(np.float64)
        data["density"][3] = np.nan if kind == "nan_density" else 1.0e300
    elif kind == "nan_energy":
        data["energy"] = np.zeros(len(data["id"]))
        data["energy"][3] = np.nan
    elif kind == "nan_wall_normal":
        data["wall_normal"] = np.zeros((len(data["id"]), 3))
        data["wall_normal"][np.flatnonzero(data["kind"] == 1)[0], 1] = np.nan
    elif kind == "level_one":
        data["level"] = np.ones(len(data["id"]), dtype=np.int32)
    elif kind in ("solid_out_of_range", "solid_swapped"):
        wall, below = data["kind"] == 1, data["position"][:, 1] < 0.0
        solid = np.zeros(len(data["id"]), dtype=np.int32)
        if kind == "solid_out_of_range":
            solid[wall] = 7
        else:
            solid[wall & below], solid[wall & ~below] = 2, 1
        data["solid"] = solid
    elif kind == "deep_wall":
        data["position"][np.flatnonzero(data["kind"] == 1)[0], 1] = -1.0
    elif kind == "no_walls":
        fluid = data["kind"] == 0
        data = {name: values[fluid] for name, values in data.items()}
    elif kind == "huge_id":
        data["id"][0] = 2**60
    elif kind == "float_dimension":
        pass   # the attribute below
    elif kind in ("fluid_in_slack", "fluid_past_slack"):
        # the first fluid particle 0.1 h or 0.3 h below the ylo wall (h = 1.3 dx = 3.25e-5 m):
        # the health check takes 0.2 h, and so does a file start
        first = np.flatnonzero(data["kind"] == 0)[0]
        data["position"][first, 1] = -(0.1 if kind == "fluid_in_slack" else 0.3) * 3.25e-5
    elif kind == "coincident":
        # a second fluid particle on the first's place (a row written twice, new ids)
        fluid = np.flatnonzero(data["kind"] == 0)
        data["position"][fluid[1]] = data["position"][fluid[0]]
    elif kind == "too_fast":
        # a start 400 times faster than the flow the input's body force drives
        data["velocity"] = np.zeros((len(data["id"]), 3))
        data["velocity"][data["kind"] == 0, 0] = 0.01
    else:
        sys.exit(f"make_bad_particles: unknown kind '{kind}'")
    with h5py.File(out, "w") as f:
        f.attrs["dimension"] = np.float64(dimension) if kind == "float_dimension" else \
            np.int32(dimension)
        for name, values in data.items():
            f["particles/" + name] = values


if __name__ == "__main__":
    main(*sys.argv[1:4])
