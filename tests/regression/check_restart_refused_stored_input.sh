#!/usr/bin/env bash
# A checkpoint whose stored input this version refuses (written before a rule was added:
# here a circle moving across its own surface, refused since 56b1164) continues with the
# given input: a warning names the refused key, the wall and body particles are laid
# again from the given input (the circle's walls at rest), exit status 0. Before, every
# restart check was skipped without a word and the circle went on moving.
# usage: check_restart_refused_stored_input.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM WORKDIR PYTHON
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 work=$6 python=$7
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
input() { cat <<EOB
&run
    case_name = 'px'
    t_end = 100.0
    max_steps = $1
/
&output
    output_dir = 'out'
/
&domain
    dimension = 2
    box_lo = 0.0, 0.0
    box_hi = 1.0e-3, 1.0e-3
    boundary = 'periodic', 'periodic', 'wall', 'wall'
    dx = 5.0e-5
/
&fluid
    nu = 1.0e-7
    body_force = 5.0e-4, 0.0
    velocity_scale = 1.0e-4
    length_scale = 1.0e-3
/
&body
    shape = 'circle'
    centre = 5.0e-4, 5.0e-4
    radius = 1.5e-4
    velocity = $2
/
EOB
}
input 20 "0.0, 0.0" > first.nml
input 20 "1.0e-4, 0.0" > refused.nml
input 40 "0.0, 0.0" > again.nml
run first.nml > first.log 2>&1 || { echo "the first run failed:"; cat first.log; exit 1; }
# what a build before the rule wrote: the moving circle's input and wall velocities
"$python" - <<'PY' || exit 1
import h5py
with h5py.File('out/px_checkpoint_000020.h5', 'r+') as f:
    f.attrs['input'] = open('refused.nml').read()
    p = f['particles']
    s = p['solid'][:]
    v = p['velocity'][:]
    v[s == s.max(), 0] = 1.0e-4
    p['velocity'][...] = v
PY
run again.nml --restart out > again.log 2>&1 || { echo "the restart failed:"; cat again.log; exit 1; }
grep -q "warning: restart: the input stored in '[^']*' is refused by this version (.*velocity(1): must be 0" again.log || {
    echo "no warning naming the refused stored input:"; cat again.log; exit 1; }
grep -q "wall and body particles were laid again" again.log || {
    echo "the walls were not laid again:"; cat again.log; exit 1; }
"$python" - <<'PY' || exit 1
import h5py, numpy as np, sys
p = h5py.File('out/px_000040.h5', 'r')['particles']
s = p['solid'][:]
top = np.abs(p['velocity'][:][s == s.max()]).max()
if top != 0.0:
    sys.exit(f"the circle's wall particles still move: |v| = {top}")
PY
echo "continued with a warning, the circle's walls laid again at rest"
