"""``robodyn bench urdf``: the example-robot-data table (docs/urdf_robots.md) parsed: one row per
installed URDF, counts in its summary equal to its rows, a reason on every refusal, DOF equal to
Pinocchio's; the script itself on a few robots; and (marked ``urdf_table``, a step of its own in
``.ci/run``) the whole table run again, every row and count compared with the committed file."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import pinocchio as pin
import pytest

from robodyn_ros.bench import urdf as bench_urdf
from robodyn_ros.urdf import example_robot_data_dir

DOC = Path(__file__).resolve().parent.parent / 'docs' / 'urdf_robots.md'
ROW = re.compile(r'^\| ([^|]+) \| `([^`]+)` \| (\d+|—) \| (runs|refused|failed|timeout) \| ([\w—?]+) \| (.*) \|$')


def parse(text: str):
    """``(summary counts {'runs': n, 'total': n, cause words: n, 'with <method>': n}, rows [(robot, file,
    dof, verdict, text, method)])``."""
    m = re.search(r'\*\*(\d+) of (\d+) run\*\* \((.*?)\)\. Refused: (.*?)\.(?: Failed or timed out: (\d+)\.)?\n',
                  text)
    assert m, 'summary line missing'
    counts = {'runs': int(m.group(1)), 'total': int(m.group(2)), 'failed': int(m.group(5) or 0)}
    for part in m.group(3).split(', '):
        n, words = part.split(' ', 1)
        counts[words] = int(n)
    for part in m.group(4).split(', '):
        if part != 'none':
            n, words = part.split(' ', 1)
            counts[words] = int(n)
    rows = []
    for line in text.splitlines():
        r = ROW.match(line)
        if r:
            rows.append((r.group(1), r.group(2), None if r.group(3) == '—' else int(r.group(3)), r.group(4),
                         r.group(6), r.group(5)))
    return counts, rows


def _consistent(counts, rows):
    assert counts['total'] == len(rows)
    assert counts['runs'] == sum(r[3] == 'runs' for r in rows)
    methods = {r[5] for r in rows if r[3] == 'runs'}
    assert methods <= {'rk4', 'rosenbrock2', 'radau'}, methods
    for m in methods:
        assert counts[f'with {m}'] == sum(r[3] == 'runs' and r[5] == m for r in rows)
    assert counts['failed'] == sum(r[3] in ('failed', 'timeout') for r in rows)
    refused = [r for r in rows if r[3] == 'refused']
    by_words = {words: key for key, words, _ in bench_urdf.CAUSES}
    assert sum(n for w, n in counts.items() if w in by_words) == len(refused)
    for r in refused:
        assert r[4].strip(), r
    stiff = [r for r in refused if r[4].startswith('stiff at the default step')]
    assert counts.get(bench_urdf.CAUSES[0][1], 0) == len(stiff)


def test_the_committed_table_has_every_installed_urdf_and_consistent_counts():
    counts, rows = parse(DOC.read_text())
    installed = {rel for rel, _ in bench_urdf.urdf_files()}
    assert {r[1] for r in rows} == installed and len(rows) == len(installed) == 69
    _consistent(counts, rows)
    assert counts["runs"] >= 66  # before the implicit integrator: 45 (21 refused as stiff at 1 ms)


def test_the_table_dof_equals_pinocchio_nv():
    """DOF of every robot the table lists with one, against Pinocchio's model of the same file (a
    URDF ``floating`` joint is a free flyer there too: 6 DOF), less the joints locked for having no mass
    below them (Pinocchio keeps them: its ABA would divide by zero on them); romeo's two hands lock 24."""
    _, rows = parse(DOC.read_text())
    d = example_robot_data_dir()
    checked, locked = 0, {}
    for robot, rel, dof, verdict, text, _ in rows:
        if dof is not None:
            m = re.search(r'locked \((\d+) joints? in all\)', text)
            locked[robot] = int(m.group(1)) if m else 0
            assert dof == pin.buildModelFromUrdf(str(d / rel)).nv - locked[robot], robot
            checked += 1
    assert checked >= 50 and locked['romeo'] == 24


def test_the_script_on_four_robots_tabulates_runs_refusals_and_their_words(tmp_path, capsys):
    out = tmp_path / 'table.md'
    args = bench_urdf.add_arguments(__import__('argparse').ArgumentParser()).parse_args(
        ['--only', 'double_pendulum_simple', 'ur3', 'xarm7', 'solo12', '--out', str(out)])
    assert bench_urdf.main(args) == 0
    counts, rows = parse(out.read_text())
    _consistent(counts, rows)
    assert counts['runs'] == 3 and counts['total'] == 4
    by = {r[0]: r for r in rows}
    solo = example_robot_data_dir() / by['solo12'][1]
    assert by['solo12'][2:4] == (pin.buildModelFromUrdf(str(solo)).nv, 'runs')  # on a fixed base, as robodyn run
    assert by['double_pendulum_simple'][2:4] == (2, 'runs')
    assert by['double_pendulum_simple'][4] == ('`effort="0" read as no limit (2 joints)`; '
                                               '`velocity="0" read as no limit (2 joints)`')
    assert by['ur3'][3] == 'refused' and by['ur3'][4] == "`robot 'ur3': no <link> element: nothing to simulate`"
    # xarm7's damping (2-10 N·m·s/rad on light links, |λ| = 1.6e5 1/s) is stiff at 1 ms: auto runs it implicitly
    assert by['xarm7'][3] == 'runs' and by['xarm7'][5] == 'rosenbrock2', by['xarm7']
    assert by['solo12'][5] == 'rk4' and by['double_pendulum_simple'][5] == 'rk4'
    assert out.read_text() in capsys.readouterr().out


def test_readme_and_docs_urdf_quote_the_table_counts():
    counts, rows = parse(DOC.read_text())
    stiff = sum(r[3] == 'refused' and r[4].startswith('stiff at the default step') for r in rows)
    other = sum(r[3] != 'runs' for r in rows) - stiff
    root = DOC.parent.parent
    for f in (root / 'README.md', root / 'docs' / 'urdf.md'):
        text = ' '.join(f.read_text().split())
        m = re.search(r'of the (\d+) URDFs of example-robot-data [\d.]+, (\d+) run with defaults \(`robodyn run FILE '
                      r'--duration 0.2`: (\d+) with rk4, (\d+) with rosenbrock2.*?\); (\d+) are refused as stiff at '
                      r'the default 1 ms step.*?and (\d+) for what their files hold', text, flags=re.I)
        assert m, f
        assert tuple(int(x) for x in m.groups()) == (counts['total'], counts['runs'], counts.get('with rk4', 0),
                                                     counts.get('with rosenbrock2', 0), stiff, other), f


@pytest.mark.urdf_table
def test_the_whole_table_run_now_gives_the_committed_rows_and_counts(tmp_path, capsys):
    """Every example-robot-data URDF through ``robodyn run FILE --duration 0.2`` (``robodyn bench urdf``,
    two at a time): the counts of this run (runs, by integrator, refusals by cause) and each row (DOF,
    verdict, integrator, the reason or warnings printed) equal those of docs/urdf_robots.md, whose counts
    README.md and docs/urdf.md quote (test_readme_and_docs_urdf_quote_the_table_counts)."""
    out = tmp_path / 'table.md'
    args = bench_urdf.add_arguments(argparse.ArgumentParser()).parse_args(['--out', str(out), '--jobs', '2'])
    assert bench_urdf.main(args) == 0
    counts, rows = parse(out.read_text())
    _consistent(counts, rows)
    assert len(rows) == 69 and counts['runs'] == sum(r[3] == 'runs' for r in rows)
    committed_counts, committed = parse(DOC.read_text())
    assert counts == committed_counts, (counts, committed_counts)
    assert len(committed) == len(rows)
    for now, then in zip(rows, committed):
        assert now == then, (now, then)
    capsys.readouterr()
