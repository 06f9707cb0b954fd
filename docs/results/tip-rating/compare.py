#!/usr/bin/env python3
"""Side by side: a `bowden bench transfer` run (joint rating, as shipped) and the same units
re-tuned and re-evaluated with `[safety] never_worse_tip` (run.sh). Prints Markdown.

usage: compare.py SRC OUT [SRC OUT ...]

For each pair: tune's choice per unit under both ratings, then per controller and path set the
mean reduction vs uncalibrated over units x paths (position, orientation, joint MAE; by vision
and by truth) with the worst cell in brackets, and every cell worse than uncalibrated.
"""
import glob, json, os, re, sys

PATHS = ('random', 'circle', 'zigzag')
METRICS = (('pos_mean_mm', 'position'), ('rot_mean_deg', 'orientation'), ('joint', 'joint MAE'))


def reduction(c, u, src, key):
    if key == 'joint':
        a, b = sum(c['joint_' + src]['mae_deg']), sum(u['joint_' + src]['mae_deg'])
    else:
        a, b = c['task_' + src][key], u['task_' + src][key]
    return 100.0 * (1.0 - a / b)


def choice(controller_toml):
    text = open(controller_toml).read()
    mode = re.search(r'^mode = "(\w+)"', text, re.M).group(1)
    mu = re.search(r'^prior_weight = ([\d.e-]+)', text, re.M)
    arch = lambda key: re.search(rf'^{key} = "models/([\w-]+?)_(?:forward|inverse)', text, re.M).group(1)
    return (mode + (f' μ = {float(mu.group(1)):g}' if mu and mode == 'newton' else '')
            + f' ({arch("model_fwd")} fwd, {arch("model_inv")} inv)')


def collect(root):
    """{(evaluation, controller): {(metric, source): [reductions]}}, violations, choices."""
    cells, worse, chosen = {}, [], {}
    units = sorted(glob.glob(os.path.join(root, 'units', '*', 'unit-*')))
    if not units:
        sys.exit(f'compare.py: no units under {root}')
    for u in units:
        name = '/'.join(u.split(os.sep)[-2:])
        chosen[name] = choice(os.path.join(u, 'controller.toml'))
        for ev in ('eval', 'eval-large'):
            path = os.path.join(u, ev, 'summary.json')
            if not os.path.exists(path):
                sys.exit(f'compare.py: {path} missing (unit not finished?)')
            by = {(c['trajectory'], c['controller']): c for c in json.load(open(path))['cells']}
            for ctl in ('paper', 'newton'):
                for t in PATHS:
                    for key, what in METRICS:
                        for src in ('vision', 'truth'):
                            r = reduction(by[(t, ctl)], by[(t, 'uncalibrated')], src, key)
                            cells.setdefault((ev, ctl), {}).setdefault((key, src), []).append(r)
                            if r < 0:
                                worse.append(f'{ev} {ctl}: {name} {t}, {what}, {src}: {r:+.1f} %')
    return cells, worse, chosen


def fmt(v):
    return f'{sum(v) / len(v):+.1f} [{min(v):+.1f}]'


for src_dir, tip_dir in zip(sys.argv[1::2], sys.argv[2::2]):
    a, b = collect(src_dir), collect(tip_dir)
    print(f'### `{src_dir}` (joint rating) against `{tip_dir}` (tip rating)\n')
    print('| unit | tune chose, joint rating | tune chose, tip rating |\n|---|---|---|')
    for name in a[2]:
        print(f'| {name} | {a[2][name]} | {b[2].get(name, "–")} |')
    print('\nMean reduction vs uncalibrated over units × paths, % (worst cell):\n')
    head = ' | '.join(f'{w}, {s}' for _, w in METRICS for s in ('vision', 'truth'))
    print(f'| paths | controller | rating | {head} | cells worse than uncalibrated |')
    print('|---' * 4 + '|---' * 6 + '|')
    for ev in ('eval', 'eval-large'):
        for ctl in ('paper', 'newton'):
            for label, (cells, worse, _) in (('joint', a), ('tip', b)):
                row = ' | '.join(fmt(cells[(ev, ctl)][(k, s)]) for k, _ in METRICS for s in ('vision', 'truth'))
                n = sum(1 for w in worse if w.startswith(f'{ev} {ctl}:'))
                paths = 'shipped' if ev == 'eval' else 'large'
                print(f'| {paths} | {ctl} | {label} | {row} | {n} |')
    for label, (_, worse, _) in (('joint rating', a), ('tip rating', b)):
        if worse:
            print(f'\nWorse than uncalibrated, {label}:\n')
            for w in worse:
                print(f'- {w}')
    print()
