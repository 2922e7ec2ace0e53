"""``robodyn bench peers`` on a very short run: every row reports its figures, the split of a step is a
partition of the whole (non-negative parts summing to it), and a row's recording is a valid MCAP read by
mcap's own reader. No timing is asserted: the figures are benchmark output."""
from __future__ import annotations

import math

import pytest
from mcap.reader import make_reader

from robodyn_ros.bench import peers

#: simulated seconds of each run here (the bench's rows run 20-300 s)
DURATION = 0.2
#: how far the sum of the split's parts may stray from the whole (a part clamped at 0 when the noise
#: between the runs it is derived from made it negative), as a fraction of the whole
SUM_TOLERANCE = 0.1


@pytest.fixture(scope='module')
def measured(tmp_path_factory):
    keep = tmp_path_factory.mktemp('peers')
    rows = peers.measure(list(peers.ROWS), duration=DURATION, repeat=1, keep=str(keep))
    return rows, peers.report(rows, 1)


def test_every_row_reports_its_figures(measured):
    rows, text = measured
    assert list(rows) == list(peers.ROWS)
    for name, f in rows.items():
        for key in ('cpu', 'wall', 'rss', 'rss_before', 'mujoco_cpu', 'mujoco_wall', 'mujoco_rss', 'mujoco_rss_before',
                    'ratio_cpu', 'ratio_wall'):
            assert f[key] is not None and math.isfinite(f[key]) and f[key] > 0, (name, key, f[key])
        assert abs(f['duration'] - DURATION) < 1e-9 and f['steps'] > 0
        assert set(f['kernels']) <= {'generic', 'generated'} and f['kernels']
        assert f['messages'] > 0
        # the resident set before the run within the peak (1 %: the kernel's RSS counters are approximate)
        assert f['rss_before'] <= 1.01 * f['rss'] and f['mujoco_rss_before'] <= 1.01 * f['mujoco_rss']
        assert f'| `{name}`, {DURATION:g} s |' in text and f'| `{name}` |' in text
    assert rows['a1_stand']['method'] == 'rosenbrock2' and rows['stanford_arm']['method'] == 'rk4'
    assert rows['a1_stand']['kernels'] == ['generic']     # a tree on a ground stays on the generic kernels


def test_the_split_is_a_partition_of_the_whole(measured):
    rows, _ = measured
    for name, f in rows.items():
        sp = f['split']
        assert set(sp) == set(peers.PARTS)
        assert all(v >= 0.0 for v in sp.values()), (name, sp)
        assert abs(sum(sp.values()) - f['whole']) <= SUM_TOLERANCE * f['whole'], (name, sp, f['whole'])
        # and without the recording, the run without a recorder, which those parts are derived from
        bare = f['none_cpu'] / f['steps'] * 1e6
        assert abs(sum(sp[k] for k in peers.PARTS if k != 'recording') - bare) <= SUM_TOLERANCE * bare, (name, sp, bare)
        assert sp['dynamics'] > 0 and sp['recording'] > 0, (name, sp)
        assert (sp['contact'] > 0) == (name == 'a1_stand'), (name, sp)   # only a1_stand stands on a ground
        assert f['fd'] > 0 and f['bm'] > 0


def test_a_rows_recording_is_a_valid_mcap(measured):
    rows, _ = measured
    for name, f in rows.items():
        with open(f['recording'], 'rb') as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            topics = {c.topic for c in summary.channels.values()}
            n = sum(1 for _ in reader.iter_messages())
        assert summary.statistics.message_count == f['messages'] == n, name
        assert {'/joint_states', '/tf', '/diagnostics', '/robot_description'} <= topics, (name, topics)
        assert all(s.encoding == 'ros2msg' for s in summary.schemas.values())
