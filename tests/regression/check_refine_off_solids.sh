#!/usr/bin/env bash
# Regression: a developed channel flow with a circle 1.17 spacings above the lower wall
# (CHANNEL.nml), refined offline, keeps every fluid particle at least 0.4 new spacings from
# the walls and bodies, as coarsening and same-level remeshing do. Where the construction's
# wall rules met under the circle it put one 0.38 new spacings from the lower wall (a 3D
# closed box with a sphere: nine, down to 0.31).
# usage: check_refine_off_solids.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM CHANNEL.nml WORKDIR PYTHON
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 channel=$6 work=$7 python=$8
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
cp "$channel" flow.nml
run flow.nml > flow.log 2>&1 || fail "the channel run failed:" flow.log
checkpoint=$(ls flow/*_checkpoint_*.h5 | tail -1)
run --remesh refine "$checkpoint" refined.h5 > refine.log 2>&1 || \
    fail "the refine failed:" refine.log
"$python" - refined.h5 <<'PY' || exit 1
import sys
import h5py
import numpy as np

g = h5py.File(sys.argv[1], "r")["particles"]
x = g["position"][...][g["kind"][...] == 0][:, :2]
dx_new = 1.5e-3
# the solids of channel_body_near_wall.nml: the walls, the circle, the rectangle
walls = np.minimum(x[:, 1], 0.06 - x[:, 1])
circle = np.hypot(x[:, 0] - 0.03, x[:, 1] - 0.0135) - 0.01
lo, hi = np.array([0.08, 0.035]), np.array([0.1, 0.0555])
outside = np.maximum(np.maximum(lo - x, x - hi), 0.0)
rect = np.where(np.all((x > lo) & (x < hi), axis=1),
                -np.min(np.minimum(x - lo, hi - x), axis=1), np.hypot(*outside.T))
clearance = np.minimum(np.minimum(walls, circle), rect) / dx_new
worst = clearance.min()
print(f"{len(x)} fluid particles; closest to a solid {worst:.4f} new spacings "
      f"({int(np.sum(clearance < 0.4 * (1 - 1e-9)))} below 0.4)")
sys.exit(0 if worst >= 0.4 * (1 - 1e-9) else 1)
PY
