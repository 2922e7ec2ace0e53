"""The user documentation (README.md, docs/*.md) stays what it promises to be: a README a user
reads in ten minutes, no project-internal issue numbers, every bundled scene in the README's
table, and every figure printed beside its tested bound inside that bound (and not far from it)."""
from __future__ import annotations

import re
from pathlib import Path

from robodyn_ros.scene import list_scenes

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / 'README.md'] + sorted((ROOT / 'docs').glob('*.md'))


def test_readme_is_short_and_no_document_speaks_of_issues():
    assert len((ROOT / 'README.md').read_text().splitlines()) <= 350
    hits = [f'{p.name}:{i}' for p in DOCS for i, line in enumerate(p.read_text().splitlines(), 1)
            if re.search(r'\bissues?\b', line, re.IGNORECASE)]
    assert len(DOCS) >= 8 and not hits, hits


def test_readme_scene_table_names_every_bundled_scene():
    readme = (ROOT / 'README.md').read_text()
    table = readme[readme.index('## Scenes'):readme.index('## Your own robot')]
    named = set(re.findall(r'^\| `([a-z0-9_]+)`(?:, `([a-z0-9_]+)`)?', table, re.MULTILINE))
    named = {n for pair in named for n in pair if n}
    assert named == {n for n, _ in list_scenes()}


NUM = r'([0-9.]+e[-−][0-9]+)'
#: a figure or a bound in prose: 0.30, 4.9e-3, −1.8e-5, 10 % (the sign is dropped: magnitudes are compared)
FIG = r'(?<![\w.])[−-]?([0-9]+(?:\.[0-9]+)?(?:e[-−+]?[0-9]+)?)'
#: how far above its figure a printed bound may lie (the tests' ~100x rule, with room for a bound
#: shared by several cases); a lower bound ("tested > x") as far below
RATIO = 1000.0
#: figures beside a bound that breaks the rule, to be fixed: ``(file, figure, bound)``; none now
PENDING = set()


def _number(text: str) -> float:
    return float(text.replace('−', '-'))


def printed_bounds(path: Path) -> list:
    """``(figure, '<' or '>', bound, file, line number, excerpt)`` of every figure printed beside its
    tested bound in ``path``:

    * in a table row, a figure followed by its bound in brackets: '3.1e-13 relative (3e-11)',
      '6.7e-14 rad (5e-12)', '1.7e-8 m/s (bound 1e-7)' (figures in e-notation);
    * anywhere, 'FIGURE [unit words] (tested < BOUND)' or '(tested > BOUND)', and
      '(FIGURE words; tested < BOUND)' (any decimal figure; a sign is dropped), and
      'FIGURE ... FIGURE (both tested < BOUND)' (the two e-notation figures before it)."""
    out = []
    for i, line in enumerate(path.read_text().splitlines(), 1):
        if line.startswith('|'):
            for fig, bound in re.findall(NUM + r'(?: [a-zA-Z/·]+)*? \((?:bound |tolerance )?' + NUM + r'\)', line):
                out.append((_number(fig), '<', _number(bound), path.name, i, line[:70]))
        for fig, op, bound in re.findall(FIG + r'(?: ?%| [^\s();,|]+){0,3} \(tested ([<>]) ' + FIG + r' ?%?\)', line):
            out.append((_number(fig), op, _number(bound), path.name, i, line[:70]))
        for fig, op, bound in re.findall(r'\(' + FIG + r'[^();]*; tested ([<>]) ' + FIG + r' ?%?\)', line):
            out.append((_number(fig), op, _number(bound), path.name, i, line[:70]))
        for m in re.finditer(r'\(both tested ([<>]) ' + FIG + r'\)', line):   # the two figures before it
            for fig in re.findall(NUM, line[:m.start()])[-2:]:
                out.append((_number(fig), m.group(1), _number(m.group(2)), path.name, i, line[:70]))
    return out


def _breaks_the_rule(fig, op, bound) -> bool:
    if op == '<':
        return not fig < bound <= RATIO * fig
    return not bound < fig <= RATIO * bound


def test_figures_lie_inside_their_printed_bounds():
    """In every document (README.md, docs/*.md), a figure printed beside its tested bound
    (:func:`printed_bounds`) lies inside it, and the bound within :data:`RATIO` (1000x) of it: a
    bound far from its figure would let the figure grow unseen."""
    pairs = [x for p in DOCS for x in printed_bounds(p)]
    assert len(pairs) >= 40, len(pairs)
    assert {x[3] for x in pairs} >= {'README.md', 'accuracy.md', 'contact.md'}
    bad = [x for x in pairs if _breaks_the_rule(*x[:3]) and (x[3], x[0], x[2]) not in PENDING]
    assert not bad, bad
    still = {(x[3], x[0], x[2]) for x in pairs if _breaks_the_rule(*x[:3])}
    assert still == PENDING, PENDING - still    # a pending figure fixed: take it off the list


def test_the_checker_reads_each_form():
    """Each form :func:`printed_bounds` reads, and a figure outside its bound or too far inside it."""
    import tempfile
    text = ('| a | b | 3.1e-13 relative (3e-11) |\n'
            'error 2.7e-7 rad (tested < 3e-6), off by 8.7e-2 rad (tested > 1e-2)\n'
            '| 0.30 rad (4.7e-2 at rest; tested > 5e-3) | −1.8e-5 m (tested < 1e-4) | 3.7 % (tested < 10 %) |\n'
            'to ≤ 8e-13 relative, and v̇ to ≤ 3e-12 (both tested < 1e-10)\n')
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / 'x.md'
        p.write_text(text)
        got = [x[:3] for x in printed_bounds(p)]
    assert sorted(got) == sorted([(3.1e-13, '<', 3e-11), (2.7e-7, '<', 3e-6), (8.7e-2, '>', 1e-2), (4.7e-2, '>', 5e-3),
                                  (1.8e-5, '<', 1e-4), (3.7, '<', 10.0), (8e-13, '<', 1e-10), (3e-12, '<', 1e-10)]), got
    assert not any(_breaks_the_rule(*x) for x in got)
    assert _breaks_the_rule(2e-5, '<', 1e-5) and _breaks_the_rule(1e-16, '<', 1e-12)
    assert _breaks_the_rule(1e-3, '>', 1e-2) and _breaks_the_rule(1.0, '>', 1e-4)
