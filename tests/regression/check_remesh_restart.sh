#!/usr/bin/env bash
# Regression: run Poiseuille at L/20 briefly, refine its checkpoint offline (sphremesh
# --remesh refine) on NP ranks and on 1 rank (the same particles, fields to round-off),
# continue the refined checkpoint at L/40 for a few steps, and check that a restart with the
# old dx is refused; an OUT that exists, is IN or cannot be created, or whose OUT.tmp
# exists, is refused.
# usage: check_remesh_restart.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM COARSE.nml FINE.nml WORKDIR
#        PYTHON COMPARER
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 coarse=$6 fine=$7 work=$8 python=$9
comparer=${10}
run() { local n=$1; shift; "$mpiexec" "$np_flag" "$n" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work/fine" && cd "$work" || exit 1

run "$np" "$coarse" > coarse.log 2>&1 || fail "the L/20 run failed:" coarse.log
checkpoint=$(ls output/*_checkpoint_*.h5 | tail -1)
run "$np" --remesh refine "$checkpoint" refined.h5 > remesh.log 2>&1 || \
    fail "--remesh refine failed:" remesh.log
run 1 --remesh refine "$checkpoint" refined_1.h5 > remesh_1.log 2>&1 || \
    fail "--remesh refine on 1 rank failed:" remesh_1.log
# OUT is always a new file: refining into an existing one (here IN itself, then the result
# of the first remesh) is refused and leaves the file as it was
cp refined.h5 refined_copy.h5
if run 1 --remesh refine refined.h5 refined.h5 > same.log 2>&1; then
    fail "a remesh onto its own input was accepted:" same.log
fi
grep -q "OUT 'refined.h5' is IN" same.log || fail "no message for OUT = IN:" same.log
if run 1 --remesh refine "$checkpoint" refined.h5 > exists.log 2>&1; then
    fail "a remesh onto an existing file was accepted:" exists.log
fi
grep -q "OUT 'refined.h5' exists: .* never replaces one" exists.log || \
    fail "no message for an existing OUT:" exists.log
cmp -s refined.h5 refined_copy.h5 || fail "a refused remesh changed refined.h5"
# an OUT whose folder does not exist is refused before the work, with nothing written
if run 1 --remesh refine "$checkpoint" no_such_folder/refined.h5 > folder.log 2>&1; then
    fail "a remesh into a missing folder was accepted:" folder.log
fi
grep -q "cannot create OUT 'no_such_folder/refined.h5' (its folder is missing or not " \
    folder.log || fail "no message for an OUT that cannot be created:" folder.log
grep -q "remesh: .* -> no_such_folder" folder.log && \
    fail "the remesh ran before OUT was found unwritable:" folder.log
# OUT.tmp, where the checkpoint goes first, is never replaced either: a file of that name,
# or a link there (whose target was truncated), is refused and left as it was
echo "notes, not to be lost" > kept.h5.tmp
echo "data behind a link" > target.dat && ln -s target.dat linked.h5.tmp
for out in kept linked; do
    if run 1 --remesh refine "$checkpoint" $out.h5 > tmp_$out.log 2>&1; then
        fail "a remesh over an existing $out.h5.tmp was accepted:" tmp_$out.log
    fi
    grep -q "'$out.h5.tmp' exists (left by an interrupted remesh" tmp_$out.log || \
        fail "no message for an existing $out.h5.tmp:" tmp_$out.log
    [ -e $out.h5 ] && fail "$out.h5 was written although $out.h5.tmp exists"
done
[ "$(cat kept.h5.tmp)" = "notes, not to be lost" ] || fail "kept.h5.tmp was changed"
[ "$(cat target.dat)" = "data behind a link" ] || fail "the link's target was changed"
# the new particles (positions, ids, kinds) bit for bit; the fields handed on by each rank
# for its part to round-off (sums in another order); pressure follows from the density
"$python" "$comparer" refined.h5 refined_1.h5 --ignore rank mass density pressure velocity \
    energy > compare.log 2>&1 || fail "the refined particles depend on the rank count:" compare.log
"$python" "$comparer" refined.h5 refined_1.h5 --tolerance 1e-12 --ignore rank pressure \
    > compare_fields.log 2>&1 || \
    fail "the refined fields depend on the rank count:" compare_fields.log
# 10 x 20 fluid particles at L/20: 40 rows of 20 at L/40 (the wall rule of sph_refine
# between facing walls: one wall's surface row dropped, the set shifted by dx/4)
grep -q "remesh refine at t = .*: fluid particles 200 -> 800, dx  5.000E-05 ->  2.500E-05 m" \
    remesh.log || fail "unexpected counts in the remesh log:" remesh.log
# the fluid next to each wall at half a new spacing (12.5 um), none closer, none inside, with
# masses that match their volume (the mirrored transfer): within 5 % of the median mass
"$python" - refined.h5 > rows.log 2>&1 <<'EOF_PY' || fail "wrong first rows:" rows.log
import sys, h5py, numpy as np
with h5py.File(sys.argv[1], "r") as f:
    fluid = f["particles/solid"][:] == 0
    y = f["particles/position"][:, 1][fluid]
    m = f["particles/mass"][fluid]
d = np.minimum(y, 1.0e-3 - y)
first = d < 2e-5
ratio = m[first] / np.median(m)
print("closest fluid to a wall:", d.min(), "farthest of the first rows:", d[first].max(),
      "their mass / median mass:", ratio.min(), "..", ratio.max())
ok = abs(d.min() - 12.5e-6) < 0.1e-6 and first.sum() == 40 and d[first].max() < 12.6e-6
ok = ok and abs(ratio - 1.0).max() < 0.05
sys.exit(0 if ok else 1)
EOF_PY
# the refined velocities carry the coarse flow (0.92 % from the analytic start-up profile at
# 0.02 s): 0.66 % at the new particles; 3.5 % while the transfer's images across the walls
# carried the velocity even about them (the first new row at 2.3 times its speed)
"$python" - refined.h5 > refined_error.log 2>&1 <<'EOF_PY' || \
    fail "the refined velocities are off the flow:" refined_error.log
import sys, h5py, numpy as np, f90nml
with h5py.File(sys.argv[1], "r") as f:
    fluid = f["particles/solid"][:] == 0
    y = f["particles/position"][:, 1][fluid]
    u = f["particles/velocity"][:, 0][fluid]
    t = float(f.attrs["time"])
    nml = f90nml.reads(f.attrs["input"])
nu, g, L = float(nml["fluid"]["nu"]), float(nml["fluid"]["body_force"][0]), 1.0e-3
k = 2 * np.arange(200)[:, None] + 1
exact = g / (2 * nu) * y * (L - y) - (4 * g * L**2 / (nu * np.pi**3 * k**3) * np.sin(
    np.pi * k * y / L) * np.exp(-k**2 * np.pi**2 * nu * t / L**2)).sum(0)
error = 100 * np.sqrt(((u - exact)**2).sum() / (exact**2).sum())
print("refined at t = %g s: relative L2 error %.4f %%" % (t, error))
sys.exit(0 if error < 0.8 else 1)
EOF_PY
for what in mass momentum; do
    change=$(grep "^  $what" remesh.log | sed 's/.*change[^0-9]*\([0-9.E+-]*\)).*/\1/')
    awk -v c="$change" 'BEGIN { exit !(c + 0 < 1e-12) }' || \
        fail "$what not conserved to 1e-12 (relative change '$change'):" remesh.log
done
grep -q "^  time .* s (.* us per particle)" remesh.log || fail "no cost line:" remesh.log

run "$np" "$fine" --restart refined.h5 > fine.log 2>&1 || \
    fail "the L/40 continuation failed:" fine.log
grep -q "particles: .* real (fluid 800)" fine.log || fail "unexpected continuation:" fine.log
# no density jump: the fluid density stays within 0.5 % of rho0 in every progress line
awk '/\.\.[0-9]/ { split($5, r, "\\.\\."); if (r[1] < 995 || r[2] > 1005) bad = 1 }
     END { exit bad }' fine.log || fail "density left rho0 +- 0.5 %:" fine.log
ls fine/*_checkpoint_*.h5 > /dev/null 2>&1 || fail "the continuation wrote no checkpoint"
# proxy of the 1 s criterion (doc/user-guide.md recipe: 0.135 % against 0.177 % at L/40 from
# the start): at 0.0225 s the continuation's error is 0.571 % (L/40 from the start 0.22 %,
# L/20 0.86 %; without the wall rule 3.7 %). It carries the coarse run's lead in the start-up
# (above), which the L/40 operator takes out over the channel's time, not in 19 steps; the
# transfer's images with the velocity even about the walls gave 0.385 %: the first row's
# excess speed, taken out of every particle by the momentum correction, cancelled that lead
error=$(grep -o "relative L2 = *[0-9.]*" fine.log | tail -1 | grep -o "[0-9.]*$")
awk -v e="$error" 'BEGIN { exit !(e + 0 > 0 && e + 0 < 0.65) }' || \
    fail "L2 error after refining $error % (expected < 0.65 %):" fine.log

# the L/20 input cannot continue the L/40 checkpoint
if run "$np" "$coarse" --restart refined.h5 > wrong.log 2>&1; then
    fail "a restart with the old dx was accepted:" wrong.log
fi
grep -q "the checkpoint's particles have spacing dx" wrong.log || \
    fail "no dx message:" wrong.log
# nor an input of another geometry (a wider box, x faces made walls): the checkpoint holds
# the particles laid for its own (such restarts ran on, half empty or without the walls)
sed 's/^    box_hi = 0.5e-3, 1.0e-3/    box_hi = 1.0e-3, 1.0e-3/' "$coarse" > wider.nml
if run 1 wider.nml --restart "$checkpoint" > wider.log 2>&1; then
    fail "a restart in a wider box was accepted:" wider.log
fi
grep -q "the checkpoint's box differs from &domain box_lo / box_hi" wider.log || \
    fail "no box message:" wider.log
sed -e "s/'periodic', 'periodic', 'wall', 'wall'/'wall', 'wall', 'wall', 'wall'/" \
    -e "s/^ *analytic = .*/    analytic = 'none'/" "$coarse" > walled.nml
if run 1 walled.nml --restart "$checkpoint" > walled.log 2>&1; then
    fail "a restart with other faces was accepted:" walled.log
fi
grep -q "the checkpoint's face 1 is 'periodic' but &domain boundary(1) = 'wall'" walled.log || \
    fail "no face message:" walled.log
echo "refined $checkpoint, continued at L/40: $(grep -o 'relative L2 = *[0-9.]* %' fine.log)"
