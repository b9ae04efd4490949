#!/usr/bin/env bash
# Regression: a closed 3D box with a lid and a sphere (CLOSED.nml), developed to 1 s, refined
# and coarsened offline: no fluid pair closer than 0.4 new spacings and no fluid particle
# closer than that to a wall or the sphere. The refinement put nine particles as close as
# 0.31 new spacings to the walls, where the wall rules of the box's edges meet; the
# coarsening left a pair 0.395 apart next to a wall, where its rows are put half a spacing
# off the walls after the relaxation.
# usage: check_remesh_closed_box.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM CLOSED.nml WORKDIR PYTHON
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 closed=$6 work=$7 python=$8
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
cp "$closed" flow.nml
run flow.nml > flow.log 2>&1 || fail "the closed-box run failed:" flow.log
checkpoint=$(ls flow/*_checkpoint_*.h5 | tail -1)
for mode in refine coarsen; do
    run --remesh "$mode" "$checkpoint" "$mode.h5" > "$mode.log" 2>&1 || \
        fail "the $mode failed:" "$mode.log"
done
"$python" - refine.h5 coarsen.h5 <<'PY' || exit 1
import sys
import h5py
import numpy as np
from scipy.spatial import cKDTree

bad = False
for path, spacing in zip(sys.argv[1:3], (0.5e-4, 2.0e-4)):
    g = h5py.File(path, "r")["particles"]
    x = g["position"][...][g["kind"][...] == 0]
    walls = np.minimum(x, 1.0e-3 - x).min(axis=1)
    sphere = np.linalg.norm(x - [0.5e-3, 0.45e-3, 0.5e-3], axis=1) - 0.2e-3
    clearance = np.minimum(walls, sphere).min() / spacing
    pair = cKDTree(x).query(x, k=2)[0][:, 1].min() / spacing
    ok = clearance >= 0.4 * (1 - 1e-9) and pair >= 0.4 * (1 - 1e-9)
    bad |= not ok
    print(f"{path}: {len(x)} fluid particles, closest pair {pair:.4f} and closest to a "
          f"solid {clearance:.4f} new spacings (limit 0.4){'' if ok else '  FAILED'}")
sys.exit(1 if bad else 0)
PY
