"""``robodyn bench urdf``: every example-robot-data URDF through ``robodyn run FILE --duration 0.2``.

Each file is run as a new user would run it, in its own process (``python -m robodyn_ros.cli run
FILE --duration 0.2 --backend B``, default settings otherwise), and tabulated: it runs (with the
warnings it printed, condensed), or it is refused and why (the one-line refusal, with its cause
named: stiff at the default step, ``<mimic>``, inertia, ...). ``--out docs/urdf_robots.md``
writes the table (``make bench`` does). Needs the test extras (example-robot-data).

The backend defaults to ``numba`` (the generic compiled kernels: every robot shares one
compilation); the generated backend gives the same verdicts and only adds a per-model
compilation to each run's time. DOF is the number of velocity coordinates (a floating base
counts 6), from the importer; mimic joints count among them (the notes say how many).
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

HELP = 'every example-robot-data URDF through `robodyn run FILE --duration 0.2`: runs, or refused and why'
#: simulated seconds of each run
DURATION = 0.2
#: wall seconds a run may take before it is reported as a timeout
TIMEOUT = 900
#: refusal causes, in the order they are tested (first match wins) and listed
CAUSES = [('stiff', 'stiff at the default step (needs an implicit integrator)', r'is unstable for this system'),
          ('mimic', '`<mimic>` joint', r'<mimic'),
          ('inertia', 'inertia not positive semi-definite', r'inertia is not positive semi-definite'),
          ('empty', 'no `<link>` in the file', r'no <link> element'),
          ('massless', 'moving links without mass', r'zero-mass moving link|missing <inertial> on a moving link'),
          ('singular', 'singular mass matrix', r'mass matrix is (singular|not finite)'),
          ('other', 'other', r'')]
#: warnings condensed for the notes column: (pattern, words)
NOTES = [(r'<limit effort="0">.* on (\d+) joint', 'effort="0" read as no limit ({} joints)'),
         (r'<limit velocity="0">.* on (\d+) joint', 'velocity="0" read as no limit ({} joints)'),
         (r'a motion of joints? (.*?) meets no inertia there\): armature (\S+) ', 'armature {1} kg·m² on {0} (M singular at q = 0)'),
         (r'(\d+) moving links? without <inertial>: .*? density (\S+) kg', '{} links: inertia inferred from geometry at {} kg/m³'),
         (r'(\d+) numbers? with a trailing dot', '{} numbers with a trailing dot read as strtod does'),
         (r"joint '([^']*)': a spherical joint", 'spherical joint {}'),
         (r"link '([^']*)' .*accepted as given", 'inertia of {} breaks the triangle inequality: kept as given'),
         (r"link '([^']*)' .*balanced as MuJoCo", 'inertia of {} balanced'),
         (r'with no mass below .*?locked as fixed: (.*?)(?:, with the (?:\d+ joints that mimic|joint that mimics) \w+)? \((\d+) joints? in all\)',
          'no mass below {}: locked ({} joints in all)'),
         (r'ignored elements that are not URDF: (.*)', 'ignored {}'),
         (r'ignored what follows </robot>', 'ignored bytes after </robot>')]


@dataclass
class Row:
    """One URDF's result: file (relative to the robots directory), dof (or None), verdict 'runs' |
    'refused' | 'failed' | 'timeout', cause (a CAUSES key, refusals only), text (the refusal or
    failure line), notes (condensed warnings), method (the integrator the run used: what
    ``integrator: auto`` chose, read from the run summary)."""

    file: str
    dof: int | None
    verdict: str
    cause: str = ''
    text: str = ''
    notes: tuple = ()
    method: str = ''


def add_arguments(p):
    """Options of the URDF table."""
    p.add_argument('--out', default=None, help='also write the markdown table to this file')
    p.add_argument('--backend', default='numba', choices=('numpy', 'numba', 'generated'),
                   help='kernels of the runs (default numba: one compilation shared by every robot)')
    p.add_argument('--jobs', type=int, default=2, help='runs in parallel (default 2)')
    p.add_argument('--only', nargs='*', default=None, help='file names (stems) to run; default every URDF')
    return p


def urdf_files(only=None) -> list:
    """``[(relative path, absolute path)]`` of the example-robot-data URDFs, sorted by robot name."""
    from ..urdf import example_robot_data_dir
    d = example_robot_data_dir()
    if d is None:
        raise SystemExit('robodyn bench urdf: example-robot-data is not installed (pip install -e ".[test]")')
    files = sorted(d.rglob('*.urdf'), key=lambda p: (p.stem.lower(), str(p)))
    return [(str(p.relative_to(d)), str(p)) for p in files if only is None or p.stem in only]


def dof(path) -> tuple:
    """``(velocity coordinates, mimic joints among them)`` of the imported robot ((None, 0) when
    it is refused)."""
    from ..urdf import UrdfError, read_urdf
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            r = read_urdf(path)
    except UrdfError:
        return None, 0
    return (sum({'revolute': 1, 'prismatic': 1, 'spherical': 3, 'free': 6}.get(s.joint_type, 0) for s in r.specs),
            sum(s.mimic is not None for s in r.specs))


def run_one(rel: str, path: str, backend: str = 'numba') -> Row:
    """Run ``robodyn run path --duration DURATION`` in a child process and classify the outcome."""
    cmd = [sys.executable, '-m', 'robodyn_ros.cli', 'run', path, '--duration', str(DURATION), '--backend', backend]
    n, n_mimic = dof(path)
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        return Row(rel, n, 'timeout', text=f'no result within {TIMEOUT} s')
    lines = p.stderr.splitlines()
    warned = [ln[len('robodyn: warning: '):] for ln in lines if ln.startswith('robodyn: warning: ')]
    errors = [ln for ln in lines if not ln.startswith('robodyn: warning: ')]
    notes = tuple(_note(w) for w in warned) + \
        ((f'{n_mimic} mimic joint{"s follow others" if n_mimic > 1 else " follows another"}',) if n_mimic else ())
    if p.returncode == 0:
        m = re.search(r'^integrator\s+(\S+)', p.stdout, flags=re.M)
        return Row(rel, n, 'runs', notes=notes, method=m.group(1) if m else '?')
    text = _strip(errors[-1] if errors else f'exit status {p.returncode}', path)
    if p.returncode == 2:
        cause = next(k for k, _, pat in CAUSES if re.search(pat, text))
        return Row(rel, n, 'refused', cause, text, notes)
    return Row(rel, n, 'failed', text=text, notes=notes)


def _strip(line: str, path: str) -> str:
    """An error line without the program's prefix and the file's path."""
    for prefix in ('robodyn run: simulation stopped: ', 'robodyn run: '):
        if line.startswith(prefix):
            line = line[len(prefix):]
            break
    return line[len(path) + 2:] if line.startswith(path + ': ') else line


def _note(warning: str) -> str:
    for pat, words in NOTES:
        m = re.search(pat, warning)
        if m:
            return words.format(*m.groups())
    return warning.split(': ', 1)[-1]


def _reason(r: Row) -> str:
    if r.cause == 'stiff':
        m = re.search(r'\|λ\| = ([^ ]+) 1/s', r.text)
        return f'stiff at the default step: fastest mode \\|λ\\| = {m.group(1) if m else "?"} 1/s'
    return _code(r.text)


def _code(text: str) -> str:
    """Text as a code span for a table cell (tags shown as written, '|' escaped)."""
    return '`' + text.replace('`', "'").replace('|', '\\|') + '`' if text else ''


def markdown(rows: list, backend: str) -> str:
    """The table with its heading and the counts by verdict and cause."""
    from importlib.metadata import version
    runs = [r for r in rows if r.verdict == 'runs']
    by_method = sorted({r.method for r in runs})
    refused = [r for r in rows if r.verdict == 'refused']
    others = [r for r in rows if r.verdict not in ('runs', 'refused')]
    by_cause = [(k, words, sum(r.cause == k for r in refused)) for k, words, _ in CAUSES]
    out = ['# example-robot-data URDFs in robodyn_ros', '',
           f'Every URDF of example-robot-data {version("example-robot-data")} run as it is: '
           f'`robodyn run FILE --duration {DURATION:g}` with default settings (integrator auto at 1 ms: rk4 where '
           f'nothing is stiff, rosenbrock2 where passive forces are; backend {backend}). '
           'Made by `robodyn bench urdf --out docs/urdf_robots.md` (part of `make bench`); CI runs the whole table '
           '(`pytest -m urdf_table`, which `.ci/run` runs) and compares every row and count with this file.', '',
           f'**{len(runs)} of {len(rows)} run** (' +
           ', '.join(f'{sum(r.method == m for r in runs)} with {m}' for m in by_method) + '). Refused: ' +
           (', '.join(f'{n} {words}' for _, words, n in by_cause if n) or 'none') + '.' +
           (f' Failed or timed out: {len(others)}.' if others else ''), '',
           '| robot | file | DOF | result | integrator | reason (refused) or notes (warnings printed) |',
           '|---|---|---|---|---|---|']
    for r in rows:
        name = os.path.splitext(os.path.basename(r.file))[0]
        what = _reason(r) if r.verdict != 'runs' else '; '.join(_code(n) for n in r.notes)
        out.append(f'| {name} | `{r.file}` | {r.dof if r.dof is not None else "—"} | {r.verdict} | '
                   f'{r.method or "—"} | {what} |')
    return '\n'.join(out) + '\n'


def main(args) -> int:
    """Run every URDF, print the table, optionally write it to ``--out``."""
    files = urdf_files(args.only)
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = list(pool.map(lambda f: run_one(f[0], f[1], args.backend), files))
    text = markdown(rows, args.backend)
    print(text, flush=True)
    if args.out:
        with open(args.out, 'w') as f:
            f.write(text)
    return 0
