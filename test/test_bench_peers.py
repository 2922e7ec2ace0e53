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
                    'ratio_cpu', 'ratio_wall', 'none_cpu'):
            assert f[key] is not None and math.isfinite(f[key]) and f[key] > 0, (name, key, f[key])
        assert abs(f['duration'] - DURATION) < 1e-9 and f['steps'] > 0
        assert set(f['kernels']) <= {'generic', 'generated'} and f['kernels']
        assert f['messages'] > 0
        # the resident set before the run within the peak (1 %: the kernel's RSS counters are approximate)
        assert f['rss_before'] <= 1.01 * f['rss'] and f['mujoco_rss_before'] <= 1.01 * f['mujoco_rss']
        assert len(f['ratio_pairs_none']) == 1 and f['ratio_pairs_none'][0] == f['mujoco_cpu'] / f['none_cpu']
        assert f'| `{name}`, {DURATION:g} s |' in text and f'| `{name}` |' in text
    assert rows['a1_stand']['method'] == 'rosenbrock2' and rows['stanford_arm']['method'] == 'rk4'
    assert rows['a1_stand']['kernels'] == ['generated']   # its contact path's code, compiled first as every row's


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


def test_the_ratio_of_each_repeat_cancels_the_machines_drift():
    # synthetic children, the machine's speed changing between repeats (robodyn 1.5, 1, 3 s): with MuJoCo 2x
    # robodyn's CPU in each repeat both statistics are 2; when one repeat's MuJoCo run alone is slower (a load
    # spike during it), the ratio of the medians moves (8/3) and the median of the repeats' ratios stays 2
    def full(cpu):
        return {'cpu': cpu, 'wall': cpu, 'steps': 100, 't': 1.0, 'method': 'rk4', 'dt': 1e-3, 'rate': 100.0,
                'kernels': 'generic', 'generic_s': 0.0, 'peak_rss': 1.0, 'rss_before': 1.0, 'messages': 10,
                'sink_cpu': 0.1, 'sink_start_cpu': 0.0}
    none = {'cpu': 0.5, 'integrating_cpu': 0.4, 'dyn_step': 1e-3, 'contact_step': 0.0, 'fd': 1e-6, 'bm': 1e-6}
    runs = {'full': [full(1.0), full(2.0), full(3.0)], 'none': [none] * 3,
            'mujoco': [{'cpu': c, 'wall': c, 'peak_rss': 1.0, 'rss_before': 1.0, 'what': 'x'} for c in (3.0, 2.0, 6.0)]}
    runs['full'][0], runs['full'][1] = full(1.5), full(1.0)   # against MuJoCo 3, 2, 6
    f = peers.row_figures(runs)
    assert f['ratio_pairs'] == [2.0, 2.0, 2.0]
    assert f['ratio_cpu'] == 3.0 / 1.5   # medians 3 and 1.5
    runs['mujoco'][1]['cpu'] = 4.0        # the second repeat: MuJoCo's run 2x slower
    f = peers.row_figures(runs)
    assert f['ratio_pairs'] == [2.0, 4.0, 2.0] and f['ratio_cpu'] == 4.0 / 1.5
    assert f['ratio_pairs_wall'] == [2.0, 2.0, 2.0]   # (its wall time did not change)
    assert f['ratio_pairs_none'] == [6.0, 8.0, 12.0]   # the runs without a recorder: 0.5 s against 3, 4, 6
    text = peers.report({'x': f}, 3)
    assert '| ×2.00 (×2.00–4.00) | ×2.00 (×2.00–2.00) | ×8.00 (×6.00–12.00) |' in text
