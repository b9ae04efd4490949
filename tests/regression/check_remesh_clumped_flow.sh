#!/usr/bin/env bash
# Regression: Morris' cylinder flow at L/25, developed to 1500 s (its particles paired: nearest
# distances 0.72 dx on average, down to 0.19 dx), refined and coarsened offline.
# Refined: the set's volumes are even at the kernel's scale, its kernel sums of volumes
# (sph_disorder.py) spread at most 0.02 (std / mean; the flow's own 0.0145). Built as it was,
# the set spread 0.16 (sums 0.5-2 of the even value), and its continued run broke down at
# 5649 s; relaxed, 0.062; with the masses adjusted to the kernel sums as well, 0.006.
# Both: the relaxation keeps the flow's pairs, so issue 10's limits hold: the mean nearest
# distance half (twice) the flow's within 5 %, its CoV within 25 % of the flow's, no pair
# closer than 0.4 new spacings. Relaxed one by one, the refined mean ratio was 0.532 and the
# coarsened CoV 0.73 of the flow's.
# usage: check_remesh_clumped_flow.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM CYLINDER.nml WORKDIR
#        PYTHON SCRIPTS
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 cylinder=$6 work=$7 python=$8 scripts=$9
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
sed -e 's/^ *t_end = .*/    t_end = 1500.0/' -e 's/^ *dx = .*/    dx = 4.0e-3/' \
    -e 's/^ *output_interval = .*/    output_interval = 1500.0/' \
    -e "s#^ *output_dir = .*#    output_dir = 'flow'#" "$cylinder" > flow.nml
run flow.nml > flow.log 2>&1 || fail "the L/25 run failed:" flow.log
source=$(ls flow/cylinder_0*.h5 | grep -v checkpoint | tail -1)
run --remesh refine "$source" refined.h5 > refine.log 2>&1 || fail "the refine failed:" refine.log
run --remesh coarsen "$source" coarsened.h5 > coarsen.log 2>&1 || \
    fail "the coarsen failed:" coarsen.log
PYTHONPATH="$scripts" "$python" - "$source" refined.h5 coarsened.h5 <<'PY' || exit 1
import sys
import sph_disorder

flow, refined, coarsened = (sph_disorder.disorder(path) for path in sys.argv[1:4])
dx = 4.0e-3
checks = [("flow's pairing (mean nearest distance / dx)", flow["mean_nn"] / dx, 0.9, "<="),
          ("refined: kernel sums of volumes, std / mean", refined["volume_sum_spread"], 0.02,
           "<=")]
for name, new, factor in (("refined", refined, 0.5), ("coarsened", coarsened, 2.0)):
    ratio = new["mean_nn"] / flow["mean_nn"]
    checks += [(f"{name}: mean nearest distance ratio / {factor} - 1",
                abs(ratio / factor - 1.0), 0.05, "<="),
               (f"{name}: CoV ratio - 1", abs(new["cov_nn"] / flow["cov_nn"] - 1.0), 0.25, "<="),
               (f"{name}: minimum pair / new spacing", new["min_pair"] / (factor * dx), 0.4,
                ">=")]
bad = False
for what, value, limit, sense in checks:
    ok = value <= limit if sense == "<=" else value >= limit * (1.0 - 1.0e-9)
    bad |= not ok
    print(f"{what}: {value:.4g} (limit {sense} {limit}){'' if ok else '  FAILED'}")
print(f"count {flow['count']} -> {refined['count']} (refined), {coarsened['count']} "
      f"(coarsened); flow's kernel sums spread {flow['volume_sum_spread']:.3g}")
sys.exit(1 if bad else 0)
PY
