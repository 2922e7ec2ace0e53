"""The issue-15 section of ``robodyn bench speed`` runs and its figures have the order of magnitude
the README quotes (a sanity bound, ~100x either way; the figures themselves are benchmark
output, never timed assertions)."""
from __future__ import annotations

import argparse

from robodyn_ros.bench import speed

#: docs/speed.md, "Recording at the speed of the dynamics" (stanford_arm): recorder per period,
#: batched, and messages per period; the docs print the sanity bound beside the figure
README_RECORDER_US = 22.0
README_MESSAGES = 11


def test_recording_section_measures_every_figure_of_the_issue():
    args = argparse.Namespace(quick=True, duration=0.3, repeat=1, figures={})
    text = speed.section_recording(args, ['stanford_arm'])
    r = args.figures['recording']['stanford_arm']
    # joint_states, 7 wrenches, /tf, /clock, effort_commands (+ diagnostics every 10th, the start's two)
    assert abs(r['messages'] - README_MESSAGES) < 0.2
    assert README_RECORDER_US / 100 < r['batched_period'] * 1e6 < README_RECORDER_US * 100
    assert 0 < r['zstd_period'] < r['batched_period']
    assert 0 < r['full'] < r['advance'] and r['ratio'] == r['full'] / r['advance']
    assert r['blocks'] > 0.9                     # stanford_arm runs in compiled blocks
    assert r['mujoco'] > 0                       # the MuJoCo peer ran, with its state copied out
    assert 'zstd 1 (written)' in text and '| stanford_arm |' in text
