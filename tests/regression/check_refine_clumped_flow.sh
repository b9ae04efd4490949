#!/usr/bin/env bash
# Regression: Morris' cylinder flow at L/25, developed to 1500 s (its particles paired: nearest
# distances 0.72 dx on average, down to 0.19 dx), refined offline. The refined set's volumes
# are even at the kernel's scale: the kernel sums of volumes (sph_disorder.py) spread at most
# 0.1 (std / mean). Built as it was, the set spread 0.16 (sums 0.5-2 of the even value), and
# its continued run broke down at 5649 s; relaxed, 0.06. The relaxation keeps the pairs: the
# mean nearest distance half the flow's within 5 % and no pair closer than 0.4 new spacings
# (issue 10's limits), which relaxing the pairs apart missed (0.532).
# usage: check_refine_clumped_flow.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM CYLINDER.nml WORKDIR
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
PYTHONPATH="$scripts" "$python" - "$source" refined.h5 <<'PY' || exit 1
import sys
import sph_disorder

flow, refined = (sph_disorder.disorder(path) for path in sys.argv[1:3])
ratio = refined["mean_nn"] / flow["mean_nn"]
dx_new = 2.0e-3
checks = [("kernel sums of volumes, std / mean", refined["volume_sum_spread"], 0.1, "<="),
          ("flow's pairing (mean nearest distance / dx)", flow["mean_nn"] / 4.0e-3, 0.9, "<="),
          ("mean nearest distance ratio", abs(ratio - 0.5) / 0.5, 0.05, "<="),
          ("minimum pair / new spacing", refined["min_pair"] / dx_new, 0.4, ">=")]
bad = False
for what, value, limit, sense in checks:
    ok = value <= limit if sense == "<=" else value >= limit * (1.0 - 1.0e-9)
    bad |= not ok
    print(f"{what}: {value:.4g} (limit {sense} {limit}){'' if ok else '  FAILED'}")
print(f"count {flow['count']} -> {refined['count']}, flow's sums spread "
      f"{flow['volume_sum_spread']:.3g}")
sys.exit(1 if bad else 0)
PY
