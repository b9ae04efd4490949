#!/usr/bin/env python3
"""Drag on a body in a periodic lattice of bodies (Morris, Fox & Zhu 1997, sec. 4.3) against
the body force on the fluid, and its convergence with resolution.

    scripts/body_drag.py OUTPUT_DIR [OUTPUT_DIR ...] [--case NAME] [--body cylinder]
                         [--time-averaged] [--max-imbalance 1.0]
                         [--figure drag.png [--labels A,B,...]]

Each directory's case name is that of its one <case>_forces.csv unless --case names it, so
runs of different inputs compare directly (for example output/cylinder against
output/cylinder_multires).

For each run: the force on the body along the body force (rows of <case>_forces.csv,
averaged over the last `--fraction` of the run's time to smooth the pressure noise), the
body force on the fluid, rho0 F times the fluid area (volume in 3D) of the box without the
body, and their ratio in percent; the mean fluid velocity U and the lattice's resistance
F_cell / (mu U_D), against Sangani & Acrivos where they apply.

At steady state the drag equals rho0 F times the fluid area whatever the resolution (the
force sums are antisymmetric), so its changes between resolutions measure how well each run
has settled, not the discretisation. The quantity that carries the discretisation error is
the drag per unit flow: the resistance. With several runs (coarse to fine) the script prints
the changes of the drag, of the mean velocity and of the resistance between successive
resolutions and their ratios. Exits 1 when an imbalance exceeds --max-imbalance percent, when the
mean fluid velocity is farther than --max-reference-deviation percent from Sangani &
Acrivos' (for creeping flow), or, with --require-convergence, when a change of the
resistance is not at most half the previous one.

--figure draws the drag of each row over rho0 F A_fluid against time (1 is the balance, with
its 1 % band) and the mean fluid velocity of each snapshot against time, with Sangani &
Acrivos' Stokes value where it applies; the shaded time is the one averaged.

Body force and pressure gradient: a body force F on the fluid alone drives the same flow as
a mean pressure gradient G = rho0 F (the fluid's equations are the same), but the linear
pressure also pushes on the body, so in the pressure-driven problem of Sangani & Acrivos and
of Darcy's law the force per body is G times the cell's area (volume), not the fluid's:
F_cell = drag / (1 - c), c the solid fraction.
"""
import argparse
import csv
import glob
import math
import os
import re
import sys

import h5py
import numpy as np

from sph_snapshot import SnapshotError, complete_snapshots, header, spacing


def snapshots(output_dir, case):
    """(time, path) of the run's complete snapshots; unreadable ones skipped with a line."""
    try:
        found = complete_snapshots(output_dir, case, 'body_drag')
    except SnapshotError as problem:
        raise SystemExit(f'body_drag: {problem}') from None
    if not found:
        raise SystemExit(f'body_drag: no complete snapshot {case}_*.h5 in {output_dir}')
    return found


def input_and_spacing(found):
    """The resolved input stored in the newest of the snapshots `found` (snapshots()) and its
    spacing of level 0 (sph_snapshot.spacing: the file's attribute dx, else the input's; the
    input keeps the spacing the run began with, also after an in-run remesh)."""
    try:
        head = header(found[-1][1])
        return head['attrs'].get('input', ''), spacing(head)
    except SnapshotError as problem:
        raise SystemExit(f'body_drag: {problem}') from None


def values(text, key, group=None):
    if group:
        m = re.search(r'^&' + group + r'\b(.*?)^/', text, re.M | re.S)
        if not m:
            raise SystemExit(f'body_drag: no &{group} in the stored input')
        text = m.group(1)
    m = re.search(r'^\s*' + key + r'\s*=\s*(.*?)(?=^\s*\w+\s*=|^/|\Z)', text, re.M | re.S)
    if not m:
        raise SystemExit(f"body_drag: the stored input has no '{key}'")
    return m.group(1)


def numbers(s):
    return [float(v) for v in re.findall(r'[-+]?\d+\.?\d*(?:[eE][-+]?\d+)?', s)]


def body_groups(text):
    """The &body groups of the stored input, each as its own text (a &region around a body
    has a shape too: it is no body)."""
    return ['&body\n' + m.group(1) + '/\n'
            for m in re.finditer(r'^&body\b(.*?)^/', text, re.M | re.S)]


def body_measure(text, name, dim, extent):
    """Area (2D) or volume (3D) of the named body from its &body group; a 3D cylinder runs
    through the box along its axis (extent: the box's side lengths)."""
    for group in body_groups(text):
        if re.search(r"name\s*=\s*'" + re.escape(name) + "'", group):
            shape = re.search(r"shape\s*=\s*'(\w+)'", group).group(1)
            if shape in ('circle', 'sphere', 'cylinder'):
                r = numbers(values(group, 'radius'))[0]
                if shape == 'sphere':
                    return 4.0 / 3.0 * math.pi * r**3
                if shape == 'cylinder' and dim == 3:
                    axis = re.search(r"axis\s*=\s*'(\w)'", group)
                    return math.pi * r**2 * extent['xyz'.index(axis.group(1) if axis else 'z')]
                return math.pi * r**2
            lo = np.array(numbers(values(group, 'lo'))[:dim])
            hi = np.array(numbers(values(group, 'hi'))[:dim])
            return float(np.prod(hi - lo))
    raise SystemExit(f"body_drag: no &body named '{name}' in the stored input")


def sangani_acrivos_speed(text, dim, lo, hi, drag, nu, rho0):
    """Mean fluid velocity of Stokes flow through a periodic array of bodies driven so that
    each body carries the force F = drag / (1 - c) of the pressure-driven problem (per unit
    length in 2D; see the module's docstring), from Sangani & Acrivos' dilute expansions, U_D
    the superficial velocity (cell average, bodies included), c the solid fraction; the mean
    over the fluid is U_D / (1 - c). None unless one circle in a square cell or one sphere in
    a cubic cell.
      square array of cylinders (1982, Int. J. Multiphase Flow 8:193):
        F / (mu U_D) = 4 pi / (-ln(c)/2 - 0.738 + c - 0.887 c^2 + 2.038 c^3);
      simple cubic array of spheres (1982, Int. J. Multiphase Flow 8:343; Hasimoto 1959):
        F / (6 pi mu a U_D) = 1 / (1 - 1.7601 x + x^3 - 1.5593 x^6 + 3.9799 x^8
        - 3.0734 x^10), x = c^(1/3) (2.008 at c = 0.027 as Zick & Homsy's Table 2)."""
    side = hi[0] - lo[0]
    if any(abs((hi[a] - lo[a]) - side) > 1e-12 * side for a in range(dim)):
        return None
    groups = body_groups(text)
    shapes = [re.search(r"shape\s*=\s*'(\w+)'", g).group(1) for g in groups]
    radius = numbers(values(groups[0], 'radius'))[0] if len(shapes) == 1 else None
    if dim == 2 and shapes == ['circle']:
        c = math.pi * radius**2 / side**2
        k = 4.0 * math.pi / (-0.5 * math.log(c) - 0.738 + c - 0.887 * c**2 + 2.038 * c**3)
    elif dim == 3 and shapes == ['sphere']:
        c = 4.0 / 3.0 * math.pi * radius**3 / side**3
        x = c ** (1.0 / 3.0)
        k = 6.0 * math.pi * radius / (1.0 - 1.7601 * x + x**3 - 1.5593 * x**6 +
                                       3.9799 * x**8 - 3.0734 * x**10)
    else:
        return None
    return drag / (1.0 - c) / (k * nu * rho0) / (1.0 - c)


def case_of(output_dir, case):
    """The case name of a run directory: `case` when given, else that of its one
    <case>_forces.csv."""
    if case is not None:
        return case
    found = sorted(glob.glob(os.path.join(output_dir, '*_forces.csv')))
    if len(found) != 1:
        raise SystemExit(f'body_drag: {output_dir} holds {len(found)} *_forces.csv files; '
                         'name the run with --case')
    return os.path.basename(found[0])[:-len('_forces.csv')]


def speed_series(found, axis):
    """(time, mass-weighted mean fluid velocity along the body force) of each readable
    snapshot of `found` (snapshots()): the superficial velocity of Darcy's law times the
    porosity."""
    series = []
    for time, name in found:
        try:
            with h5py.File(name, 'r') as f:
                g = f['particles']
                fluid = g['kind'][...] == 0
                m = g['mass'][...][fluid]
                speed = float(np.sum(m * g['velocity'][...][fluid, axis]) / np.sum(m))
        except (OSError, KeyError) as problem:
            print(f'body_drag: skipped {name}: not readable ({problem})', file=sys.stderr)
            continue
        series.append((time, speed))
    return series


def mean_speed(series, t_from):
    """The mean of speed_series' speeds from t_from on (NaN when none)."""
    speeds = [speed for time, speed in series if time >= t_from]
    return float(np.mean(speeds)) if speeds else float('nan')


def draw(path, runs):
    """The figure of the runs (dicts: label, rows' times and drags over rho0 F A_fluid,
    speed series, Sangani & Acrivos' speed or None, the averaged window's start): the drag
    over time against the body force on the fluid (1, with the 1 % band), and the mean
    fluid velocity over time against the reference."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    left.axhspan(0.99, 1.01, color='0.85', label='body force on the fluid, 1 %')
    left.axhline(1.0, color='0.4', lw=0.8)
    references = []
    for run in runs:
        line, = left.plot(run['times'], run['ratios'], lw=1.0, label=run['label'])
        if run['speeds']:
            t, u = zip(*run['speeds'])
            right.plot(t, u, 'o-', ms=3, lw=1.0, color=line.get_color(), label=run['label'])
        if run['reference'] is not None and all(
                abs(run['reference'] - r) > 1e-3 * abs(r) for r in references):
            references.append(run['reference'])
    for k, reference in enumerate(references):
        right.axhline(reference, color='k', ls='--', lw=0.8,
                      label="Sangani & Acrivos (Stokes)" if k == 0 else None)
    start = min(run['t_from'] for run in runs)
    for ax in (left, right):
        ax.axvspan(start, max(run['times'][-1] for run in runs), color='C0', alpha=0.06)
        ax.set_xlabel('t [s]')
        ax.legend(fontsize=8)
    top = max(1.2, min(2.0, max(max(run['ratios']) for run in runs) * 1.05))
    left.set_ylim(0.0, top)
    left.set_ylabel('drag / (rho0 F A_fluid)')
    left.set_title('drag (step means of each row), averaged in the shaded time', fontsize=9)
    right.set_ylabel('mean fluid velocity [m/s]')
    right.set_title('mean fluid velocity of each snapshot', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def time_averaged(rows, last, key, out):
    """The mean over the rows `last` (the tail of `rows`) of their step means `key`, each
    weighted by the time since the previous row (a row's mean covers that time)."""
    if key not in rows[0] or rows[0][key] is None:
        raise SystemExit(f'body_drag: {out} has no {key} column (written since 618240b)')
    times = [float(r['time']) for r in rows]
    first = len(rows) - len(last)
    weights = [times[k] - times[k - 1] if k > 0 else 0.0 for k in range(first, len(rows))]
    if sum(weights) <= 0.0:
        raise SystemExit(f'body_drag: {out}: the rows averaged cover no time')
    return float(np.average([float(r[key]) for r in last], weights=weights))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('output_dirs', nargs='+')
    ap.add_argument('--case', default=None,
                    help="the runs' case name (&run case_name); by default each directory's "
                         "from its one <case>_forces.csv")
    ap.add_argument('--body', default='cylinder',
                    help="the body's &body name (default cylinder)")
    ap.add_argument('--fraction', type=float, default=0.5,
                    help='average the rows of the last fraction of the run time (0 < f <= 1)')
    ap.add_argument('--time-averaged', action='store_true',
                    help="average the rows' step means (Fx_mean, ...: the force averaged over "
                         "the steps since the previous row), weighted by the time each covers, "
                         "instead of the instantaneous forces of the rows")
    ap.add_argument('--max-imbalance', type=float, default=None,
                    help='percent: fail when the drag and the body force on the fluid differ '
                         'by more than this')
    ap.add_argument('--require-convergence', action='store_true',
                    help='fail unless each change of the resistance between successive runs '
                         'is at most half the previous one')
    ap.add_argument('--max-reference-deviation', type=float, default=None,
                    help="percent: fail when the mean fluid velocity is farther from Sangani & "
                         "Acrivos' (only for creeping flow, where their expansion holds)")
    ap.add_argument('--figure', default=None,
                    help='write a PNG of the drag and the mean fluid velocity over time')
    ap.add_argument('--labels', default=None,
                    help="the runs' names in the figure, comma-separated (default L/n)")
    args = ap.parse_args()
    # (a negative fraction indexed past the rows: a traceback)
    if not 0.0 < args.fraction <= 1.0:
        ap.error('--fraction must lie in (0, 1]')
    for out in args.output_dirs:
        if not os.path.isdir(out):
            ap.error(f"'{out}' is not a directory (give the runs' output folders)")
    labels = args.labels.split(',') if args.labels is not None else None
    if labels is not None and len(labels) != len(args.output_dirs):
        ap.error(f'--labels names {len(labels)} runs, {len(args.output_dirs)} are given')
    if args.figure is not None and not args.figure.lower().endswith('.png'):
        ap.error('--figure must name a .png file')

    drags, speeds, resistances, failed, runs = [], [], [], False, []
    for index, out in enumerate(args.output_dirs):
        case = case_of(out, args.case)
        found = snapshots(out, case)
        text, dx = input_and_spacing(found)
        dim = int(numbers(values(text, 'dimension'))[0])
        lo = np.array(numbers(values(text, 'box_lo'))[:dim])
        hi = np.array(numbers(values(text, 'box_hi'))[:dim])
        rho0 = numbers(values(text, 'rho0'))[0]
        nu = numbers(values(text, 'nu'))[0]
        force = np.array(numbers(values(text, 'body_force'))[:dim])
        axis = int(np.argmax(np.abs(force)))
        cell = float(np.prod(hi - lo))
        fluid = cell - body_measure(text, args.body, dim, hi - lo)
        rows = []
        forces = os.path.join(out, f'{case}_forces.csv')
        try:
            with open(forces) as f:
                for row in csv.DictReader(f):
                    if (row.get('body') or '').strip() != args.body:
                        continue
                    if None in row.values():
                        # a last row cut short (a run killed while writing it)
                        print(f'body_drag: {forces}: skipped a short row', file=sys.stderr)
                        continue
                    rows.append(row)
        except OSError as problem:
            raise SystemExit(f'body_drag: cannot read {forces}: {problem.strerror}') from None
        if not rows:
            raise SystemExit(f"body_drag: no rows for '{args.body}' in {out}")
        t_end = float(rows[-1]['time'])
        last = [r for r in rows if float(r['time']) >= (1.0 - args.fraction) * t_end]
        key = 'F' + 'xyz'[axis]
        if args.time_averaged:
            drag = time_averaged(rows, last, key + '_mean', out)
        else:
            drag = float(np.mean([float(r[key]) for r in last]))
        expected = rho0 * force[axis] * fluid
        imbalance = 100.0 * (drag - expected) / expected
        drags.append(drag)
        series = speed_series(found, axis)
        speeds.append(mean_speed(series, (1.0 - args.fraction) * t_end))
        porosity = fluid / cell
        # drag per unit superficial flow of the pressure-driven problem (module docstring)
        resistances.append(drag / porosity / (rho0 * nu * porosity * speeds[-1]))
        reference = sangani_acrivos_speed(text, dim, lo, hi, expected, nu, rho0)
        # the figure's drag: each row's step mean where the file has them, as averaged
        shown = key + '_mean' if rows[0].get(key + '_mean') is not None else key
        runs.append({'label': labels[index] if labels else f'L/{(hi[0] - lo[0]) / dx:.0f}',
                     'times': [float(r['time']) for r in rows],
                     'ratios': [float(r[shown]) / expected for r in rows],
                     'speeds': series, 'reference': reference,
                     't_from': float(last[0]['time'])})
        print(f'{out}: dx = {dx:g} m (L/{(hi[0] - lo[0]) / dx:.0f}), {len(last)} rows from t = '
              f'{float(last[0]["time"]):g} to {t_end:g} s, drag {drag:.6e}, rho0 F A_fluid '
              f'{expected:.6e} ({"N/m" if dim == 2 else "N"}), imbalance {imbalance:+.3f} %, '
              f'mean fluid velocity {speeds[-1]:.6e} m/s' +
              ('' if reference is None else f' (Sangani & Acrivos {reference:.6e}, '
               f'{100 * (speeds[-1] - reference) / reference:+.2f} %)') +
              f', resistance F_cell / (mu U_D) {resistances[-1]:.5g}'
              f'{"" if dim == 2 else " m"}')
        if args.max_imbalance is not None and abs(imbalance) > args.max_imbalance:
            failed = True
        # (written so that a NaN fails: no fluid gave a NaN speed that passed before)
        if args.max_reference_deviation is not None and (
                reference is None or not
                abs(100 * (speeds[-1] - reference) / reference) <= args.max_reference_deviation):
            failed = True
    for name, series in (('drag', drags), ('mean velocity', speeds),
                         ('resistance', resistances)):
        for k in range(1, len(series)):
            change = series[k] - series[k - 1]
            relative = 100 * change / series[k] if series[k] != 0 else float('nan')
            line = f'{name} change {k}: {change:+.4e} ({relative:+.3f} %)'
            if k >= 2:
                # (two equal runs in a row: no change to compare with, not a division by 0)
                previous = abs(series[k - 1] - series[k - 2])
                ratio = abs(change) / previous if previous > 0 else \
                    (0.0 if change == 0 else float('inf'))
                line += f', ratio to the previous change {ratio:.3f}'
                if args.require_convergence and name == 'resistance' and ratio > 0.5:
                    failed = True
            print(line)
    if args.figure is not None:
        draw(args.figure, runs)
        print(f'body_drag: wrote {args.figure}')
    if failed:
        print('body_drag: a threshold was exceeded', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
