#!/usr/bin/env bash
# Regression: a multi-resolution run (INPUT, writing its last checkpoint to output/; 2D or 3D,
# a periodic box from the origin) keeps no two real fluid particles of one level within 0.05
# of that level's spacing (copies: the input says how they came).
# usage: check_no_coincident.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR PYTHON
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
"$mpiexec" "$np_flag" "$np" $extra "$program" "$input" > run.log 2>&1 || \
    fail "the run failed:" run.log
checkpoint=$(ls output/*_checkpoint_*.h5 | tail -1)
"$python" - "$checkpoint" <<'PY' || exit 1
import sys
import h5py
import numpy as np

f = h5py.File(sys.argv[1], "r")
g = f["particles"]
text = f.attrs["input"]
text = text.decode() if isinstance(text, bytes) else text
dx = float([line.split("=")[1] for line in text.splitlines()
            if line.strip().startswith("dx =")][0])
dim = int(f.attrs["dimension"])
box = np.array([float(v) for v in [line.split("=")[1] for line in text.splitlines()
                                   if line.strip().startswith("box_hi =")][0].split(",")[:dim]])
real = g["kind"][...] == 0
x, level = g["position"][...][real, :dim], g["level"][...][real]
bad = 0
for lv in np.unique(level):
    y = x[level == lv]
    d = y[:, None, :] - y[None, :, :]
    d -= box * np.round(d / box)                      # periodic box
    r = np.sqrt((d ** 2).sum(-1)) + np.eye(len(y)) * 1e9
    closest = r.min() / (dx / 2.0 ** lv)
    pairs = int((r < 0.05 * dx / 2.0 ** lv).sum() // 2)
    print(f"level {lv}: {len(y)} real, closest pair {closest:.3f} spacings, {pairs} within 0.05")
    bad += pairs
sys.exit(1 if bad else 0)
PY
