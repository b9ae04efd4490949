#!/usr/bin/env bash
# Regression: a uniform checkpoint becomes a multi-resolution one, both ways. A Poiseuille run
# at L/20 (velocity Verlet, whose checkpoints carry the rates its next step starts from) to
# 0.01 s; then (a) continued with the two-level input (input/poiseuille_multires.nml),
# whose regions the restart refines, and (b) refined offline (sphremesh --remesh refine IN
# OUT --regions INPUT.nml) and continued from OUT. Both reach 0.02 s with the same particles
# and fields bit for bit. (Before, the restart (a) started its first step from the uniform
# state's rates, none for the new particles: velocities 0.2 % of the peak off.) Refused with
# a message and nothing written: --regions with another mode, an input without &region
# groups, an IN that is multi-resolution already, an input of another spacing (named as the
# offline command's error, not a restart's), an input that ends before IN's time (no run
# could continue OUT with it), an OUT that exists. A band along the lower plate
# and a nested level-2 band, refined from the uniform checkpoint, hold the particles per level
# (walls included) and the real mass of the same inputs started afresh (before: the band lost
# the fine row next to the plate, 2.5 % of the mass, and kept the coarse walls under it; the
# nested band came out empty, 20 %).
# usage: check_refine_regions.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM UNIFORM.nml MULTIRES.nml
#        WORKDIR PYTHON COMPARER
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 uniform=$6 multires=$7 work=$8 python=$9
comparer=${10}
run() { local n=$1; shift; "$mpiexec" "$np_flag" "$n" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

verlet="s/^&numerics/\&numerics\n    integrator = 'verlet'/"
sed -e 's/^ *t_end = .*/    t_end = 0.01/' -e "s#^ *output_dir = .*#    output_dir = 'u'#" \
    -e 's/^ *output_times = .*/    output_times = 0.01/' -e 's/^ *dx = .*/    dx = 5.0e-5/' \
    -e "$verlet" "$uniform" > uniform.nml
for way in a b; do
    sed -e 's/^ *t_end = .*/    t_end = 0.02/' -e "s#^ *output_dir = .*#    output_dir = '$way'#" \
        -e 's/^ *output_times = .*/    output_times = 0.02/' -e "$verlet" "$multires" > $way.nml
done
run "$np" uniform.nml > uniform.log 2>&1 || fail "the uniform run failed:" uniform.log
checkpoint=$(ls u/*_checkpoint_*.h5 | tail -1)

run "$np" a.nml --restart "$checkpoint" > a.log 2>&1 || fail "the restart with regions failed:" a.log
grep -q "its regions were refined" a.log || fail "the restart did not refine the regions:" a.log
run "$np" --remesh refine "$checkpoint" refined.h5 --regions b.nml > offline.log 2>&1 || \
    fail "--remesh refine --regions failed:" offline.log
grep -q "continue with sphremesh b.nml --restart refined.h5" offline.log || \
    fail "the offline refinement does not say how to continue:" offline.log
run "$np" b.nml --restart refined.h5 > b.log 2>&1 || fail "the run from OUT failed:" b.log
snap_a=$(ls a/*_0*.h5 | grep -v checkpoint | tail -1)
snap_b=$(ls b/*_0*.h5 | grep -v checkpoint | tail -1)
"$python" "$comparer" "$snap_a" "$snap_b" > compare.log 2>&1 || \
    fail "the two ways differ at 0.02 s:" compare.log

# the set-up's particle count (walls included) and the first progress line's per-level counts
# and total real mass of a log
levels() { grep -E "^particles: |^ +level [0-9]: |^ +all levels: real mass" "$1" | \
    sed -e 's/; per step.*//' -e 's/ (drift.*//' | head -"$2"; }
sed -e 's/^ *lo = 0.0, 0.25e-3.*/    lo = 0.0, -1.0e-3/' \
    -e 's/^ *hi = 0.5e-3, 0.75e-3.*/    hi = 0.5e-3, 0.5e-3/' a.nml > wall.nml
cp a.nml nested.nml
printf "&region\n    shape = 'box'\n    lo = 0.0, 0.4e-3\n    hi = 0.5e-3, 0.6e-3\n" \
    >> nested.nml
printf "    level = 2\n/\n" >> nested.nml
for variant in wall:4 nested:5; do
    name=${variant%:*} lines=${variant#*:}
    sed -e "s#^ *output_dir = .*#    output_dir = '$name.fresh'#" \
        -e 's/^ *t_end = .*/    t_end = 0.0005/' $name.nml > $name.fresh.nml
    sed -e "s#^ *output_dir = .*#    output_dir = '$name.restart'#" $name.nml > $name.restart.nml
    run "$np" $name.fresh.nml > $name.fresh.log 2>&1 || \
        fail "the fresh $name run failed:" $name.fresh.log
    run "$np" $name.restart.nml --restart "$checkpoint" > $name.restart.log 2>&1 || \
        fail "the $name restart failed:" $name.restart.log
    levels $name.fresh.log "$lines" > $name.fresh.levels
    levels $name.restart.log "$lines" > $name.restart.levels
    [ "$(wc -l < $name.fresh.levels)" -eq "$lines" ] || fail "no level lines:" $name.fresh.log
    diff $name.fresh.levels $name.restart.levels > $name.diff || \
        fail "the $name band refined from the uniform state differs from a fresh one:" $name.diff
done

expect_refusal() {   # name, message pattern, file that must not exist, args...
    local name=$1 pattern=$2 out=$3; shift 3
    if run 1 "$@" > "$name.log" 2>&1; then fail "$name was accepted:" "$name.log"; fi
    grep -q "$pattern" "$name.log" || fail "no message for $name:" "$name.log"
    [ ! -e "$out" ] || fail "$name wrote $out"
}
expect_refusal other_mode "error in command line: --regions goes with --remesh refine" x.h5 \
    --remesh coarsen "$checkpoint" x.h5 --regions b.nml
expect_refusal no_regions "has no &region groups: nothing to refine" x.h5 \
    --remesh refine "$checkpoint" x.h5 --regions uniform.nml
expect_refusal multires_in "holds a multi-resolution state already" x.h5 \
    --remesh refine refined.h5 x.h5 --regions b.nml
sed -e 's/^ *t_end = .*/    t_end = 0.005/' b.nml > ended.nml
expect_refusal ended "error in remesh: --regions: IN '.*' is at or past the end of 'ended.nml'" \
    x.h5 --remesh refine "$checkpoint" x.h5 --regions ended.nml
sed -e 's/^ *dx = .*/    dx = 2.5e-5/' b.nml > fine.nml
expect_refusal other_spacing "error in remesh --regions: the checkpoint's particles have spacing" \
    x.h5 --remesh refine "$checkpoint" x.h5 --regions fine.nml
grep -q "evaluated anew" other_spacing.log && fail "a refused input was told of its rates:" \
    other_spacing.log
cp refined.h5 kept.h5
if run 1 --remesh refine "$checkpoint" refined.h5 --regions b.nml > exists.log 2>&1; then
    fail "an existing OUT was replaced:" exists.log
fi
grep -q "OUT 'refined.h5' exists" exists.log || fail "no message for an existing OUT:" exists.log
cmp -s refined.h5 kept.h5 || fail "the existing OUT was changed"
echo "a uniform checkpoint refined in its regions at a restart and offline: the same state"
