#!/usr/bin/env bash
# Regression: level-1 bands around two bodies refined (--remesh refine --regions) into a
# disordered 3D uniform state (INPUT: same-level remeshes every 10 steps, 30 steps) keep no two
# real fine particles closer than 0.4 fine spacings, the floor of every refinement. The
# construction from the disordered sources put pairs 0.28 spacings apart before.
# usage: check_refine_regions_disordered.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR PYTHON
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
run "$input" > uniform.log 2>&1 || fail "the uniform run failed:" uniform.log
[ "$(grep -c '^remesh same at' uniform.log)" -eq 3 ] || \
    fail "expected 3 same-level remeshes:" uniform.log
sed -e "s/mode = 'same'/mode = 'none'/" -e "s/max_steps = 30/max_steps = 36/" "$input" > regions.nml
cat >> regions.nml <<'NML'
&region
    shape = 'body'
    body = 'blk'
    distance = 0.012
    level = 1
/
&region
    shape = 'body'
    body = 'cyl'
    distance = 0.01
    level = 1
/
NML
run --remesh refine out/bd_checkpoint_000030.h5 refined.h5 --regions regions.nml \
    > refine.log 2>&1 || fail "the refinement of the regions failed:" refine.log
"$python" - refined.h5 <<'PY' || exit 1
import sys
import h5py
import numpy as np
from scipy.spatial import cKDTree

dx, box = 5.0e-3, np.array([0.16, 0.08, 0.08])     # refine_regions_disordered.nml
with h5py.File(sys.argv[1], "r") as f:
    g = f["particles"]
    real = g["kind"][...] == 0
    x, level = g["position"][...][real], g["level"][...][real]
y = x[level == 1]
periodic = np.array([True, False, True])            # walls on y
y[:, periodic] %= box[periodic]
y[:, ~periodic] += 1.0                              # no wrap: a box far larger
tree = cKDTree(y, boxsize=np.where(periodic, box, 100.0))
closest = tree.query(y, k=2)[0][:, 1].min() / (dx / 2.0)
print(f"level 1: {len(y)} real fluid particles, closest pair {closest:.3f} fine spacings")
sys.exit(0 if closest >= 0.4 else 1)
PY
