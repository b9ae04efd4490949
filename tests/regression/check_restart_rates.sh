#!/usr/bin/env bash
# Regression: a velocity-Verlet checkpoint carries the rates its next step starts from. A
# restart that only extends the run (t_end, output times) uses them and repeats the straight
# run bit for bit; one whose input changes what the rates depend on (here the body force)
# says so and evaluates them anew (before, its first kick used the old force's rates).
# usage: check_restart_rates.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM POISEUILLE.nml WORKDIR
#        PYTHON COMPARER
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8 comparer=$9
run() { local n=$1; shift; "$mpiexec" "$np_flag" "$n" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

make_input() {   # name, t_end, output_times, body force
    sed -e "s/^ *t_end = .*/    t_end = $2/" -e "s#^ *output_dir = .*#    output_dir = '$1'#" \
        -e "s/^ *output_times = .*/    output_times = $3/" -e 's/^ *dx = .*/    dx = 5.0e-5/' \
        -e "s/^ *body_force = .*/    body_force = $4, 0.0/" \
        -e "s/^&numerics/\&numerics\n    integrator = 'verlet'/" "$input" > "$1.nml"
}
make_input first 0.01 0.01 2.0e-4
make_input straight 0.02 "0.01, 0.02" 2.0e-4
make_input extended 0.02 "0.01, 0.02" 2.0e-4
make_input stronger 0.02 "0.01, 0.02" 4.0e-4
run "$np" first.nml > first.log 2>&1 || fail "the first run failed:" first.log
run "$np" straight.nml > straight.log 2>&1 || fail "the straight run failed:" straight.log
checkpoint=$(ls first/*_checkpoint_*.h5 | tail -1)
run "$np" extended.nml --restart "$checkpoint" > extended.log 2>&1 || \
    fail "the extended run failed:" extended.log
if grep -q "evaluated anew" extended.log; then
    fail "an extended run did not take the checkpoint's rates:" extended.log
fi
last() { ls "$1"/*_0*.h5 | grep -v checkpoint | tail -1; }
"$python" "$comparer" "$(last straight)" "$(last extended)" > compare.log 2>&1 || \
    fail "the extended run differs from the straight one:" compare.log
run "$np" stronger.nml --restart "$checkpoint" > stronger.log 2>&1 || \
    fail "the run with a stronger force failed:" stronger.log
grep -q "restart: the input differs from the checkpoint's in what the rates depend on" \
    stronger.log || fail "a changed body force kept the checkpoint's rates:" stronger.log
# what the checkpoint's state cannot take is refused, naming the key: another rest density
# (before: the run stopped at its first step on &health density_band, with a failure
# snapshot) and a max_steps the checkpoint is past (before: it took a step all the same)
sed -e 's/^ *rho0 = .*/    rho0 = 500.0/' extended.nml > lighter.nml
if run "$np" lighter.nml --restart "$checkpoint" > lighter.log 2>&1; then
    fail "a restart with another rho0 ran:" lighter.log
fi
grep -q "error in restart: the checkpoint's fluid has &fluid rho0 = *1.0*E+03 kg/m^3 but" lighter.log || \
    fail "no message naming rho0:" lighter.log
sed -e 's/^&run/\&run\n    max_steps = 5/' extended.nml > fewer.nml
if run "$np" fewer.nml --restart "$checkpoint" > fewer.log 2>&1; then
    fail "a restart past max_steps ran:" fewer.log
fi
grep -q "error in restart: the checkpoint is at step [0-9]*, at or past &run max_steps = 5" \
    fewer.log || fail "no message naming max_steps:" fewer.log
# a wider kernel needs more wall layers: the walls are laid again, as a fresh start lays them
# (before: the checkpoint's 3 layers were kept; with h_factor 4, where 8 were needed, the
# density fell to 940 kg/m^3 in one step)
sed -e "s/^&numerics/\&numerics\n    h_factor = 2.0/" extended.nml > wider.nml
run "$np" wider.nml --restart "$checkpoint" > wider.log 2>&1 || \
    fail "the wider run failed:" wider.log
grep -q "restart: the input changes the wall layers (3 -> 4" wider.log || \
    fail "the walls were not laid again:" wider.log
sed -e 's/^ *t_end = .*/    t_end = 1.0e-5/' -e "s#^ *output_dir = .*#    output_dir = 'wider0'#" \
    wider.nml > wider0.nml
run "$np" wider0.nml > wider0.log 2>&1 || fail "the fresh wider run failed:" wider0.log
[ "$(grep '^particles:' wider.log)" = "$(grep '^particles:' wider0.log)" ] || \
    fail "the walls laid again differ from a fresh start's:" wider.log
# and every particle's smoothing length in its files (output_dir 'extended', the extended
# run's set aside) is the wider kernel's, 2 dx (before: the checkpoint's 1.3 dx went on)
"$python" -c "
import sys, h5py, numpy as np
h = h5py.File(sys.argv[1], 'r')['particles/smoothing_length'][()]
sys.exit(0 if np.all(h == 2 * 5.0e-5) else 'smoothing lengths %s, not 2 dx' % np.unique(h))
" "$(last extended)" > h.log 2>&1 || \
    fail "the wider run's files keep the checkpoint's smoothing length:" h.log
# a time step below the time's resolution stops with a health failure naming the limits
# (before: thousands of steps at one time, writing checkpoints, until killed)
sed -e "s/^&numerics/\&numerics\n    fixed_dt = 1.0e-30/" extended.nml > frozen.nml
run "$np" frozen.nml --restart "$checkpoint" > frozen.log 2>&1
status=$?
[ "$status" -eq 3 ] || fail "a frozen time step exited with $status, not 3:" frozen.log
grep -q "error in health check: the time step 1.000E-30 s no longer advances the time" \
    frozen.log || fail "no message for the frozen time step:" frozen.log
echo "a Verlet checkpoint's rates: kept when only the run is extended, evaluated anew otherwise"
echo "another rho0 and a max_steps already passed refused; walls laid again for a wider kernel"
