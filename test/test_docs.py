"""The user documentation (README.md, docs/*.md) stays what it promises to be: a README a user
reads in ten minutes, no project-internal issue numbers, every bundled scene in the README's
table, and every accuracy figure inside the bound printed beside it."""
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


def test_accuracy_figures_lie_inside_their_printed_bounds():
    """In the accuracy tables, a figure followed by its bound in brackets — '3.1e-13 relative
    (3e-11)', '6.7e-14 rad (5e-12)' — is below that bound, and the bound within 1000x of it
    (the tests' ~100x rule, with room for a bound shared by several cases: the URDF robots'
    8.2e-16 under 1e-12)."""
    pairs = []
    for p in (ROOT / 'README.md', ROOT / 'docs' / 'accuracy.md'):
        for line in p.read_text().splitlines():
            if line.startswith('|'):
                for fig, bound in re.findall(NUM + r'(?: [a-zA-Z/·]+)*? \((?:bound |tolerance )?' + NUM + r'\)', line):
                    pairs.append((float(fig.replace('−', '-')), float(bound.replace('−', '-')), p.name, line[:60]))
    assert len(pairs) >= 30
    bad = [x for x in pairs if not x[0] < x[1] <= 2000 * x[0]]
    assert not bad, bad
