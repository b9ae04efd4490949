#!/usr/bin/env python3
"""Lid-driven cavity against Ghia, Ghia & Shin (1982, J. Comput. Phys. 48:387), Table I/II.

    scripts/cavity_ghia.py OUTPUT_DIR [--case cavity] [--fraction 0.2] [--min-snapshots 5]
                           [--figure cavity.png] [--max-rms 0.7] [--max-largest 1.5]

At each tabulated point of the two centre lines (15 each, the end points on the walls left
out) the velocity is the Gaussian-weighted mean of the fluid particles within 3 dx (weight
exp(-d^2/dx^2)), averaged over the snapshots of the last `fraction` of the run (at least
`min-snapshots` of them). Errors are in percent of the lid speed U; the lid is the moving
face (yhi), the box and U are read from the input stored in the snapshots, dx from the newest
one (its attribute dx, else its input's &domain dx). Prints one line per point and the RMS
and largest error; exits 1 when a --max-* threshold is exceeded.
"""
import argparse
import os
import re
import sys

import h5py
import numpy as np

from sph_snapshot import SnapshotError, complete_snapshots, header, spacing

# Ghia et al. (1982): u on the vertical centre line x = 1/2, v on the horizontal one y = 1/2
GHIA_Y = np.array([0.0547, 0.0625, 0.0703, 0.1016, 0.1719, 0.2813, 0.4531, 0.5000, 0.6172,
                   0.7344, 0.8516, 0.9531, 0.9609, 0.9688, 0.9766])
GHIA_X = np.array([0.0625, 0.0703, 0.0781, 0.0938, 0.1563, 0.2266, 0.2344, 0.5000, 0.8047,
                   0.8594, 0.9063, 0.9453, 0.9531, 0.9609, 0.9688])
GHIA_U = {
    100: [-0.03717, -0.04192, -0.04775, -0.06434, -0.10150, -0.15662, -0.21090, -0.20581,
          -0.13641, 0.00332, 0.23151, 0.68717, 0.73722, 0.78871, 0.84123],
    1000: [-0.18109, -0.20196, -0.22220, -0.29730, -0.38289, -0.27805, -0.10648, -0.06080,
           0.05702, 0.18719, 0.33304, 0.46604, 0.51117, 0.57492, 0.65928],
}
GHIA_V = {
    100: [0.09233, 0.10091, 0.10890, 0.12317, 0.16077, 0.17507, 0.17527, 0.05454, -0.24533,
          -0.22445, -0.16914, -0.10313, -0.08864, -0.07391, -0.05906],
    1000: [0.27485, 0.29012, 0.30353, 0.32627, 0.37095, 0.33075, 0.32235, 0.02526, -0.31966,
           -0.42665, -0.51550, -0.39188, -0.33714, -0.27669, -0.21388],
}


def input_values(text, key):
    """The numbers of `key = ...` in the namelist text stored with a snapshot."""
    match = re.search(r'^\s*' + key + r'\s*=\s*(.*?)(?=^\s*\w+\s*=|^/)', text, re.M | re.S)
    if not match:
        raise SystemExit(f"cavity_ghia: the snapshot's input has no '{key}'")
    return [float(v) for v in re.findall(r'[-+]?\d+\.?\d*(?:[eE][-+]?\d+)?', match.group(1))]


def snapshots(output_dir, case):
    """(time, path) of the run's complete snapshots; unreadable ones skipped with a line."""
    try:
        return complete_snapshots(output_dir, case, 'cavity_ghia')
    except SnapshotError as problem:
        raise SystemExit(f'cavity_ghia: {problem}') from None


def input_and_spacing(path):
    """The resolved input stored in a snapshot and its spacing of level 0 (sph_snapshot.spacing:
    the file's attribute dx, else the input's; the input keeps the spacing the run began
    with, also after an in-run remesh)."""
    try:
        head = header(path)
        return head['attrs'].get('input', ''), spacing(head)
    except SnapshotError as problem:
        raise SystemExit(f'cavity_ghia: {problem}') from None


def centre_line_means(name, lo, size, dx, lid_speed):
    """Weighted means (u on x = 1/2, v on y = 1/2) in units of the lid speed."""
    with h5py.File(name, 'r') as f:
        g = f['particles']
        x = g['position'][...]
        v = g['velocity'][...]
        fluid = g['kind'][...] == 0
    x = (x[fluid, :2] - lo) / size
    v = v[fluid, :2] / lid_speed
    h = dx / size
    u_line = [weighted(x, v[:, 0], np.array([0.5, y]), h) for y in GHIA_Y]
    v_line = [weighted(x, v[:, 1], np.array([xx, 0.5]), h) for xx in GHIA_X]
    return np.array(u_line), np.array(v_line)


def weighted(x, values, point, h):
    d2 = np.sum((x - point) ** 2, axis=1)
    near = d2 < (3.0 * h) ** 2
    if not near.any():
        raise SystemExit(f'cavity_ghia: no fluid particle within 3 dx of {point}')
    w = np.exp(-d2[near] / h**2)
    return float(np.sum(w * values[near]) / np.sum(w))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('output_dir')
    ap.add_argument('--case', default='cavity')
    ap.add_argument('--fraction', type=float, default=0.2,
                    help='average the snapshots of the last fraction of the run time '
                         '(0 < f <= 1, default 0.2)')
    ap.add_argument('--min-snapshots', type=int, default=5)
    ap.add_argument('--reynolds', type=int, choices=sorted(GHIA_U), default=None,
                    help='table to compare with; default: from U L / nu of the input')
    ap.add_argument('--figure', default=None, help='write a figure of both centre lines')
    ap.add_argument('--max-rms', type=float, default=None, help='threshold, percent of U')
    ap.add_argument('--max-largest', type=float, default=None, help='threshold, percent of U')
    args = ap.parse_args(argv)
    # (2 or 0 were taken: 2 averaged from before t = 0, 0 only the last snapshot; body_drag
    # refuses them alike)
    if not 0.0 < args.fraction <= 1.0:
        ap.error('--fraction must lie in (0, 1]')

    snaps = snapshots(args.output_dir, args.case)
    if not snaps:
        raise SystemExit(f'cavity_ghia: no complete snapshot {args.case}_*.h5 in '
                         f'{args.output_dir}')
    t_end = snaps[-1][0]
    last = [s for s in snaps if s[0] >= (1.0 - args.fraction) * t_end]
    if len(last) < args.min_snapshots:
        raise SystemExit(f'cavity_ghia: only {len(last)} snapshots in the last '
                         f'{args.fraction:g} of the run (t >= {(1 - args.fraction) * t_end:g} s);'
                         f' need {args.min_snapshots}: write snapshots more often')
    text, dx = input_and_spacing(last[-1][1])
    lo = np.array(input_values(text, 'box_lo')[:2])
    hi = np.array(input_values(text, 'box_hi')[:2])
    nu = input_values(text, 'nu')[0]
    walls = np.array(input_values(text, 'wall_velocity')).reshape(-1, 3)
    lid_speed = float(np.linalg.norm(walls[3]))
    size = float(hi[0] - lo[0])
    if lid_speed <= 0.0 or abs(hi[1] - lo[1] - size) > 1e-12 * size:
        raise SystemExit('cavity_ghia: needs a square box with a moving upper face (yhi)')
    reynolds = args.reynolds or min(GHIA_U, key=lambda r: abs(np.log(r / (lid_speed * size /
                                                                          nu))))
    u_ref, v_ref = np.array(GHIA_U[reynolds]), np.array(GHIA_V[reynolds])

    means = []
    for _, name in last:
        try:
            means.append(centre_line_means(name, lo, size, dx, lid_speed))
        except (OSError, KeyError) as problem:
            print(f'cavity_ghia: skipped {name}: not readable ({problem})', file=sys.stderr)
    if len(means) < args.min_snapshots:
        raise SystemExit(f'cavity_ghia: only {len(means)} readable snapshots in the last '
                         f'{args.fraction:g} of the run; need {args.min_snapshots}')
    u_sph = np.mean([m[0] for m in means], axis=0)
    v_sph = np.mean([m[1] for m in means], axis=0)
    err = 100.0 * np.concatenate([u_sph - u_ref, v_sph - v_ref])
    rms = float(np.sqrt(np.mean(err**2)))
    largest = float(np.max(np.abs(err)))

    print(f'cavity Re = {lid_speed * size / nu:g} (Ghia table Re = {reynolds}), '
          f'dx = L/{size / dx:.0f}, {len(last)} snapshots from t = {last[0][0]:g} '
          f'to {last[-1][0]:g} s')
    print(' line     coord      sph     ghia   err[%U]')
    for name, coord, sph, ref in (('u(y)', GHIA_Y, u_sph, u_ref), ('v(x)', GHIA_X, v_sph, v_ref)):
        for c, s, r in zip(coord, sph, ref):
            print(f' {name}  {c:8.4f} {s:8.4f} {r:8.4f} {100 * (s - r):8.3f}')
    print(f'RMS error {rms:.3f} % of U, largest {largest:.3f} % of U')

    if args.figure:
        # (a missing folder or an unknown extension: a traceback from savefig before)
        folder = os.path.dirname(args.figure) or '.'
        if not os.path.isdir(folder):
            sys.exit(f"cavity_ghia: the folder '{folder}' of --figure does not exist")
        if os.path.splitext(args.figure)[1].lower() not in ('.png', '.pdf', '.svg', '.jpg',
                                                            '.jpeg', '.eps', '.ps'):
            sys.exit(f"cavity_ghia: --figure '{args.figure}': give a .png, .pdf, .svg, .jpg "
                     "or .eps name")
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        fig, (a, b) = plt.subplots(1, 2, figsize=(9, 4))
        a.plot(u_sph, GHIA_Y, 'o-', label='sphremesh')
        a.plot(u_ref, GHIA_Y, 'ks', mfc='none', label='Ghia et al. (1982)')
        a.set_xlabel('u / U on x = L/2')
        a.set_ylabel('y / L')
        b.plot(GHIA_X, v_sph, 'o-', label='sphremesh')
        b.plot(GHIA_X, v_ref, 'ks', mfc='none', label='Ghia et al. (1982)')
        b.set_xlabel('x / L')
        b.set_ylabel('v / U on y = L/2')
        for ax in (a, b):
            ax.grid(alpha=0.3)
            ax.legend()
        fig.suptitle(f'Lid-driven cavity, Re = {reynolds}, dx = L/{size / dx:.0f}: '
                     f'RMS {rms:.2f} %, largest {largest:.2f} % of U')
        fig.tight_layout()
        fig.savefig(args.figure, dpi=120)
        print(f'figure: {args.figure}')

    failed = ((args.max_rms is not None and rms > args.max_rms) or
              (args.max_largest is not None and largest > args.max_largest))
    if failed:
        print('cavity_ghia: error above the threshold', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
