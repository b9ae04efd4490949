#!/usr/bin/env bash
# Regression: a uniform checkpoint refined offline with nested bands around a body
# (body_nested.nml: levels 1 and 2) holds, per level, the real fluid particles and mass of
# the same input started afresh within 5 %. The level-2 band is made from level 1, whose
# particles next to the body were fitted and relaxed: the construction left its irregular
# cells without centres, and the band came out 12 % short of particles and 11 % of mass.
# usage: check_refine_nested_body.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM NESTED.nml WORKDIR PYTHON
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 nested=$6 work=$7 python=$8
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
# the uniform input: the nested one without its &region groups
awk '/^&region/ {skip = 1} !skip {print} /^\// {skip = 0}' "$nested" | \
    sed "s#^ *output_dir = .*#    output_dir = 'uniform'#" > uniform.nml
sed -e 's/^ *t_end = .*/    t_end = 25.0/' "$nested" > nested.nml
run uniform.nml > uniform.log 2>&1 || fail "the uniform run failed:" uniform.log
checkpoint=$(ls uniform/*_checkpoint_*.h5 | tail -1)
run --remesh refine "$checkpoint" refined.h5 --regions nested.nml > refine.log 2>&1 || \
    fail "--remesh refine --regions failed:" refine.log
sed -e 's/^ *t_end = .*/    max_steps = 1/' "$nested" > fresh.nml
run fresh.nml > fresh.log 2>&1 || fail "the fresh start failed:" fresh.log
fresh=$(ls fresh/*_checkpoint_*.h5 | tail -1)
"$python" - refined.h5 "$fresh" <<'PY' || exit 1
import sys
import h5py
import numpy as np

def levels(path):
    g = h5py.File(path, "r")["particles"]
    real = g["kind"][...] == 0
    level, mass = g["level"][...][real], g["mass"][...][real]
    return {lv: (int(np.sum(level == lv)), float(np.sum(mass[level == lv]))) for lv in (0, 1, 2)}

refined, fresh = levels(sys.argv[1]), levels(sys.argv[2])
bad = False
for lv in (0, 1, 2):
    (n_r, m_r), (n_f, m_f) = refined[lv], fresh[lv]
    ok = abs(n_r - n_f) <= 0.05 * n_f and abs(m_r - m_f) <= 0.05 * m_f
    bad |= not ok
    print(f"level {lv}: refined {n_r} particles, {m_r:.5g} kg; fresh {n_f}, {m_f:.5g} kg"
          f"{'' if ok else '  (more than 5 % apart)'}")
sys.exit(1 if bad else 0)
PY
