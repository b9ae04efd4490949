#!/usr/bin/env bash
# Regression: remeshing during a run (&remesh). Poiseuille at L/20 with same-level remeshing
# every 10 steps: the log states each remesh (counts, mass and momentum conserved to 1e-12,
# cost) and the run ends normally; then the same case with mode = 'refine', every_time =
# 0.01 s refines once per 0.01 s, and its last snapshot records the new spacing (refined
# again offline from there).
# usage: check_remesh_in_run.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

run "$input" > same.log 2>&1 || fail "the run with same-level remeshing failed:" same.log
n=$(grep -c "^remesh same at t = " same.log)
steps=$(grep -o "finished: [0-9]* steps" same.log | grep -o "[0-9]*")
[ "$n" -eq $((steps / 10)) ] || fail "expected $((steps / 10)) remeshes in $steps steps, got $n:" same.log
# repeated same-level remeshing keeps the count within 2 % of the original 200
awk '/^remesh same at t = / { n = $(NF - 5) + 0; if (n < 196 || n > 204) bad = 1 }
     END { exit bad }' same.log || fail "same-level remeshing changed the count by > 2 %:" same.log
for what in mass momentum; do
    worst=$(grep "^  $what" same.log | sed 's/.*change[^0-9]*\([0-9.E+-]*\)).*/\1/' | sort -g | tail -1)
    awk -v c="$worst" 'BEGIN { exit !(c + 0 < 1e-12) }' || \
        fail "$what not conserved to 1e-12 (worst relative change '$worst'):" same.log
done

sed -e "s/mode = 'same'/mode = 'refine'/" -e "s/every_steps = 10/every_time = 0.01/" \
    -e "s#output_dir = 'output'#output_dir = 'refine'#" "$input" > refine.nml
mkdir -p refine
run refine.nml > refine.log 2>&1 || fail "the run with refinement every 0.01 s failed:" refine.log
[ "$(grep -c "^remesh refine at t = " refine.log)" -eq 2 ] || \
    fail "expected 2 refinements (t = 0.01, 0.02 s):" refine.log
grep -q "fluid particles 200 -> 800, dx  5.000E-05 ->  2.500E-05 m" refine.log || \
    fail "unexpected first refinement:" refine.log
# the last snapshot records the spacing it holds (attribute dx), so an offline refinement of
# it starts from there: it took the stored input's dx (5e-5 m, two refinements before) and
# made particles 2.5e-5 apart out of a set 1.25e-5 apart
last=$(ls refine/*_0*.h5 | grep -v checkpoint | sort | tail -1)
run --remesh refine "$last" offline.h5 > offline.log 2>&1 || \
    fail "the offline refinement of $last failed:" offline.log
grep -q "fluid particles 3200 -> 12800, dx  1.250E-05 ->  6.250E-06 m" offline.log || \
    fail "the offline refinement of the last snapshot did not start from its spacing:" \
    offline.log
echo "same-level: $n remeshes in $steps steps; refine: $(grep -c '^remesh refine' refine.log)"
