#!/usr/bin/env python3
"""Write a variant of an initial-particle file for the poiseuille_short case (regression tests).

    make_bad_particles.py GOOD.h5 KIND OUT.h5

KIND: missing_position, duplicate_id, outside_box, wrong_dimension, integer_positions (the
positions stored as int16), nan_density, huge_density (1e300 kg/m^3) (one defect each), or
shuffled (the same particles, rows in a random order). GOOD.h5 is a file made by
scripts/make_initial_particles.py.
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
    else:
        sys.exit(f"make_bad_particles: unknown kind '{kind}'")
    with h5py.File(out, "w") as f:
        f.attrs["dimension"] = np.int32(dimension)
        for name, values in data.items():
            f["particles/" + name] = values


if __name__ == "__main__":
    main(*sys.argv[1:4])
