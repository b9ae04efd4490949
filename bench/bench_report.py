#!/usr/bin/env python3
"""The benchmark suite's table (bench/run): reads the run logs in OUT/logs, prints one table
of medians (with ranges) per case, integrator and rank count, and writes OUT/bench.csv and
OUT/bench.png. Then the remeshing and multi-resolution benchmarks' own tables, and the
multi-resolution cost study's plot (the thesis' Figure 5-2) as OUT/multires.png.

    bench/bench_report.py OUT

Definitions (doc/performance.md):
  wall              the step loop's wall time ("finished:" line), median over repetitions
  ns/p-step         wall x ranks / (particles x steps), particles = all real particles
  pairs/s           pairs within the kernel support (each pair once) x rate evaluations / wall
  neighbours        neighbours within the support per particle ("neighbours:" line)
  split             shares of the step loop (the "time split:" line, mean over ranks)
  bytes/particle    peak resident set of all ranks / particles ("peak memory:" line)
  efficiency        2-rank: ns/p-step on 1 rank / ns/p-step x ranks on 2 ranks
"""
import csv
import os
import re
import statistics
import sys

PARTS = ['search', 'rates', 'halo', 'integration', 'output', 'other']
LOG_NAME = re.compile(r'(?P<case>.+)_(?P<integrator>predictor_corrector|verlet)_np(?P<np>\d+)'
                      r'_r(?P<rep>\d+)\.log$')


def parse_log(path):
    """The figures of one run's log."""
    text = open(path).read()
    run = {}
    m = re.search(r'^particles: (\d+) real \(fluid (\d+)\)', text, re.M)
    run['particles'] = int(m.group(1))
    m = re.search(r'^finished: (\d+) steps to t = +\S+ s in +([0-9.]+) s wall', text, re.M)
    run['steps'], run['wall'] = int(m.group(1)), float(m.group(2))
    m = re.search(r'^peak memory: .*, +([0-9.]+) bytes per particle', text, re.M)
    run['bytes'] = float(m.group(1)) if m else float('nan')
    m = re.search(r'^time split: (.*); +([0-9.]+) s timed, (\d+) rate evaluations', text, re.M)
    parts = dict((k, float(v)) for k, v in re.findall(r'(\w+) ([0-9.]+) s \(', m.group(1)))
    run['timed'] = float(m.group(2))
    run['evaluations'] = int(m.group(3))
    for part in PARTS:
        run[part] = parts[part]
    m = re.search(r'^neighbours: ([0-9.]+) per particle', text, re.M)
    run['neighbours'] = float(m.group(1))
    return run


def median(values):
    return statistics.median(values)


def summarise(runs, np):
    """Medians (and the wall-time range) of the repetitions of one case."""
    row = {'reps': len(runs), 'particles': runs[0]['particles'], 'steps': runs[0]['steps']}
    walls = [r['wall'] for r in runs]
    row['wall'], row['wall_min'], row['wall_max'] = median(walls), min(walls), max(walls)
    row['ns'] = 1e9 * row['wall'] * np / (row['particles'] * row['steps'])
    row['ns_min'] = 1e9 * row['wall_min'] * np / (row['particles'] * row['steps'])
    row['ns_max'] = 1e9 * row['wall_max'] * np / (row['particles'] * row['steps'])
    row['neighbours'] = median([r['neighbours'] for r in runs])
    row['evaluations'] = runs[0]['evaluations']
    row['pairs_per_s'] = median([0.5 * r['neighbours'] * r['particles'] * r['evaluations'] /
                                 r['wall'] for r in runs])
    for part in PARTS:
        row[part] = median([100.0 * r[part] / max(r['timed'], 1e-12) for r in runs])
    row['bytes'] = median([r['bytes'] for r in runs])
    return row


def main():
    out = sys.argv[1]
    groups = {}
    for name in sorted(os.listdir(os.path.join(out, 'logs'))):
        m = LOG_NAME.match(name)
        if not m:
            continue
        key = (m.group('case'), m.group('integrator'), int(m.group('np')))
        groups.setdefault(key, []).append(parse_log(os.path.join(out, 'logs', name)))
    rows = []
    for key in sorted(groups, key=lambda k: (k[0][:13], groups[k][0]['particles'], k[1], k[2])):
        row = summarise(groups[key], key[2])
        row.update(case=key[0], integrator=key[1], ranks=key[2])
        rows.append(row)
    for row in rows:
        row['efficiency'] = ''
        if row['ranks'] == 2:
            one = [r for r in rows if r['case'] == row['case'] and
                   r['integrator'] == row['integrator'] and r['ranks'] == 1]
            if one:
                row['efficiency'] = '%.0f' % (100.0 * one[0]['ns'] / row['ns'])

    machine = open(os.path.join(out, 'machine.txt')).read().strip()
    print('# sphremesh benchmark suite (bench/run)')
    for line in machine.splitlines():
        print('#   ' + line)
    print('# medians over the repetitions (reps); wall [range]; split in % of the step loop')
    header = ('%-17s %-6s %2s %9s %5s %4s %20s %14s %8s %6s %5s %5s %5s %5s %4s %4s %6s %4s' %
              ('case', 'integ', 'np', 'particles', 'steps', 'reps', 'wall s [range]',
               'ns/p-step x np', 'Mpairs/s', 'neigh', 'srch%', 'rate%', 'halo%', 'intg%',
               'out%', 'oth%', 'B/part', 'eff%'))
    print(header)
    print('-' * len(header))
    for r in rows:
        print('%-17s %-6s %2d %9d %5d %4d %7.2f [%5.2f-%5.2f] %5.0f [%3.0f-%3.0f] %8.1f %6.1f '
              '%5.1f %5.1f %5.1f %5.1f %4.1f %4.1f %6.0f %4s' %
              (r['case'], 'pc' if r['integrator'] == 'predictor_corrector' else 'verlet',
               r['ranks'], r['particles'], r['steps'], r['reps'], r['wall'], r['wall_min'],
               r['wall_max'], r['ns'], r['ns_min'], r['ns_max'], r['pairs_per_s'] / 1e6,
               r['neighbours'], r['search'], r['rates'], r['halo'], r['integration'],
               r['output'], r['other'], r['bytes'], r['efficiency']))

    fields = ['case', 'integrator', 'ranks', 'particles', 'steps', 'reps', 'evaluations',
              'wall', 'wall_min', 'wall_max', 'ns', 'ns_min', 'ns_max', 'pairs_per_s',
              'neighbours'] + PARTS + ['bytes', 'efficiency']
    with open(os.path.join(out, 'bench.csv'), 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction='ignore')
        writer.writeheader()
        writer.writerows(rows)

    for name, title in [('remesh', 'remeshing throughput (sphremesh_bench_remesh)'),
                        ('remesh_jitter', 'remeshing throughput, jittered set '
                                          '(sphremesh_bench_remesh 316 all 0.8)'),
                        ('multires', 'multi-resolution cost study (sphremesh_bench_multires, '
                                     '20 steps, fastest of 3 alternations)')]:
        print('\n# ' + title)
        for np in (1, 2):
            path = os.path.join(out, '%s_np%d.txt' % (name, np))
            if os.path.exists(path):
                print(open(path).read().rstrip())
    plot(rows, os.path.join(out, 'bench.png'))
    written = [os.path.join(out, 'bench.csv'), os.path.join(out, 'bench.png')]
    studies = {np: parse_multires(os.path.join(out, 'multires_np%d.txt' % np))
               for np in (1, 2)}
    if any(studies.values()):
        plot_multires(studies, os.path.join(out, 'multires.png'))
        written.append(os.path.join(out, 'multires.png'))
    print('\n# written: %s' % ', '.join(written))


def parse_multires(path):
    """The rows of sphremesh_bench_multires' table: fine spacing (L/n), uniform particles,
    multi-resolution real and virtual particles, then per comparison (predictor-corrector,
    Verlet sub-cycled) the wall seconds per simulated second of the uniform and the
    multi-resolution run, the zones' part and the ratio. [] when the file is missing."""
    if not os.path.exists(path):
        return []
    rows = []
    for line in open(path):
        words = line.split()
        if not words or not words[0].startswith('L/'):
            continue
        numbers = [float(w) for w in words[1:] if w != '+']
        row = {'fine': words[0], 'uniform_particles': int(numbers[0]),
               'real': int(numbers[1]), 'virtual': int(numbers[2])}
        for k, name in enumerate(('pc', 'verlet')):
            uniform, multi, zones, ratio = numbers[3 + 4 * k:7 + 4 * k]
            row[name] = {'uniform': uniform, 'multi': multi, 'zones': zones, 'ratio': ratio}
        rows.append(row)
    return rows


def plot_multires(studies, path):
    """The cost study: wall time per simulated time of both runs, and their ratio, against
    the uniform run's particle count, for each comparison and rank count."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    names = {'pc': 'predictor-corrector, one step', 'verlet': 'Verlet, coarse sub-cycled'}
    for np, rows in sorted(studies.items()):
        if not rows:
            continue
        n = [r['uniform_particles'] for r in rows]
        for name, marker in (('pc', 'o'), ('verlet', 's')):
            label = '%s, %d rank%s' % (names[name], np, 's' if np > 1 else '')
            right.plot(n, [r[name]['ratio'] for r in rows], marker=marker,
                       ls='-' if np == 1 else '--', label=label)
            if name == 'verlet':
                left.plot(n, [r[name]['uniform'] for r in rows], marker='o',
                          ls='-' if np == 1 else '--', label='uniform fine, %d rank(s)' % np)
                left.plot(n, [r[name]['multi'] for r in rows], marker='s',
                          ls='-' if np == 1 else '--', label='multi-resolution, %d rank(s)' % np)
    log_axes(left, 'particles of the uniformly fine run', 'wall s per simulated s (Verlet)')
    right.axhline(0.5, color='k', ls=':', lw=0.8)
    right.text(2.2e3, 0.52, 'target 0.5', fontsize=8)
    log_axes(right, 'particles of the uniformly fine run',
             'multi-resolution / uniform wall time', log_y=False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def log_axes(ax, xlabel, ylabel, log_y=True):
    """Logarithmic particle axis (and y axis), labels, legend and grid."""
    ax.set_xscale('log')
    if log_y:
        ax.set_yscale('log')
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)
    ax.grid(True, which='both', alpha=0.3)


def plot(rows, path):
    """ns per particle-step against particles, and the time split of every row."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 5))
    series = {}
    for r in rows:
        dim = '3D' if r['case'].startswith('poiseuille3d') else '2D'
        label = '%s %s, %d rank%s' % (dim, r['integrator'].replace('_', '-'), r['ranks'],
                                      's' if r['ranks'] > 1 else '')
        series.setdefault(label, []).append(r)
    for label, rs in sorted(series.items()):
        rs.sort(key=lambda r: r['particles'])
        left.errorbar([r['particles'] for r in rs], [r['ns'] for r in rs],
                      yerr=[[r['ns'] - r['ns_min'] for r in rs],
                            [r['ns_max'] - r['ns'] for r in rs]],
                      marker='o', capsize=3, label=label)
    left.axhline(175, color='k', ls='--', lw=0.8)
    left.text(1.1e4, 180, 'target 2D: 175 ns', fontsize=8)
    left.axhline(700, color='k', ls=':', lw=0.8)
    left.text(1.1e4, 720, 'target 3D: 700 ns', fontsize=8)
    log_axes(left, 'particles', 'ns per particle-step x ranks (median, range)')
    names = ['%s %s np%d' % (r['case'].replace('poiseuille', ''),
                             'pc' if r['integrator'] == 'predictor_corrector' else 'vv',
                             r['ranks']) for r in rows]
    bottom = [0.0] * len(rows)
    for part in PARTS:
        values = [r[part] for r in rows]
        right.barh(names, values, left=bottom, label=part)
        bottom = [b + v for b, v in zip(bottom, values)]
    right.set_xlabel('share of the step loop (%)')
    right.invert_yaxis()
    right.legend(fontsize=8, ncol=6, loc='upper center', bbox_to_anchor=(0.5, -0.1))
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == '__main__':
    main()
