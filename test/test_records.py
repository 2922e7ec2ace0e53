"""The recorder's batch loops (:mod:`robodyn_ros.kernels.records`) in their three forms: compiled, their
Python source (what numba compiles, run by the interpreter) and the numpy forms that run while they are
not compiled (``fill_rows_numpy``, ``fill_headers_numpy``). Each writes the same bytes; the headers are
also checked against the MCAP spec's layout read back with ``struct``."""
import struct

import numpy as np
import pytest

from robodyn_ros.kernels import jit, records


def _rows_case(rng, K, n_values, n_stamps, width):
    template = rng.integers(0, 256, width, dtype=np.uint8)
    values = rng.standard_normal((K, n_values)) * 10.0 ** rng.integers(-300, 300, (K, n_values))
    values[0, :min(3, n_values)] = [np.nan, -np.inf, -0.0][:min(3, n_values)]
    bits = np.ascontiguousarray(values).view(np.int64)
    slots = rng.permutation((width - 8) // 8)[:n_values + n_stamps] * 8   # non-overlapping 8-byte slots
    value_at, stamp_at = slots[:n_values].astype(np.int64), slots[n_values:].astype(np.int64)
    value_col = rng.integers(0, n_values, n_values).astype(np.int64) if n_values else np.zeros(0, np.int64)
    # times: 0, under a second, past 2**32 s (the seconds wrap in the int32 field), negative (floor division)
    times = rng.integers(0, 2 ** 62, (K, 2), dtype=np.int64)
    times[0] = (0, 999_999_999)
    if K > 2:
        times[1] = (-1, -1_500_000_000)
        times[2] = (2 ** 32 * 1_000_000_000 + 7, 5_000_000_000)
    stamp_of = rng.integers(0, 2, n_stamps).astype(np.int64)
    return template, bits, value_col, value_at, times, stamp_at, stamp_of


@pytest.mark.parametrize('K,n_values,n_stamps', [(1, 0, 0), (3, 1, 1), (7, 12, 2), (64, 40, 3)])
def test_fill_rows_forms_write_the_same_bytes(K, n_values, n_stamps):
    rng = np.random.default_rng(K * 1000 + n_values)
    args = _rows_case(rng, K, n_values, n_stamps, 8 * (n_values + n_stamps) + 24)
    outs = []
    for form in (records.fill_rows, jit.python_kernel(records.fill_rows), records.fill_rows_numpy):
        out = np.full((K, args[0].size), 0xAB, dtype=np.uint8)
        form(*args, out)
        outs.append(out)
    template, bits, value_col, value_at, times, stamp_at, stamp_of = args
    # independently: each value's 8 bytes are its double's, each stamp (int32 sec, uint32 nanosec) of divmod
    k = K - 1
    for i in range(n_values):
        assert outs[0][k, value_at[i]:value_at[i] + 8].tobytes() == struct.pack('<q', int(bits[k, value_col[i]]))
    for i in range(n_stamps):
        sec, ns = divmod(int(times[k, stamp_of[i]]), 1_000_000_000)
        assert outs[0][k, stamp_at[i]:stamp_at[i] + 8].tobytes() == struct.pack('<II', sec % 2 ** 32, ns)
    rest = np.ones(template.size, dtype=bool)   # every other byte is the template's
    rest[np.r_[value_at, stamp_at].astype(np.int64)[:, None] + np.arange(8)] = False
    assert (outs[0][:, rest] == template[rest]).all()
    assert outs[0].tobytes() == outs[1].tobytes()
    assert outs[0].tobytes() == outs[2].tobytes()


@pytest.mark.parametrize('n,n_channels', [(1, 1), (5, 3), (300, 7), (1000, 40)])
def test_fill_headers_forms_write_the_same_bytes_and_sequences(n, n_channels):
    rng = np.random.default_rng(n + n_channels)
    sizes = rng.integers(31, 200, n).astype(np.int64)
    offsets = np.r_[0, np.cumsum(sizes)[:-1]].astype(np.int64)
    channels = rng.integers(0, n_channels, n).astype(np.int64)
    log_times = np.sort(rng.integers(0, 2 ** 63 - 1, n, dtype=np.int64))
    start = rng.integers(0, 2 ** 32 - 3, n_channels).astype(np.int64)   # sequences near the uint32 wrap too
    start[0] = 2 ** 32 - 2
    payload = rng.integers(0, 256, int(sizes.sum()), dtype=np.uint8)
    results = []
    for form in (records.fill_headers, jit.python_kernel(records.fill_headers), records.fill_headers_numpy):
        buf = payload.copy()
        seq = start.copy()
        form(buf, offsets, sizes, channels, log_times, seq)
        results.append((buf, seq))
    buf, seq = results[0]
    # independently: the MCAP message record header, and sequence numbers counting per channel
    count = {c: int(start[c]) for c in range(n_channels)}
    for k in range(n):
        c = int(channels[k])
        count[c] += 1
        a = int(offsets[k])
        assert buf[a:a + 31].tobytes() == struct.pack('<BQHIQQ', 5, int(sizes[k]) - 9, c, count[c] % 2 ** 32,
                                                      int(log_times[k]), int(log_times[k]))
    assert seq.tolist() == [count[c] for c in range(n_channels)]
    gaps = np.ones(payload.size, dtype=bool)
    gaps[offsets[:, None] + np.arange(31)] = False
    assert buf[gaps].tobytes() == payload[gaps].tobytes()   # nothing but the headers written
    for other_buf, other_seq in results[1:]:
        assert other_buf.tobytes() == buf.tobytes() and other_seq.tolist() == seq.tolist()


def test_interpreted_recorder_loops_are_the_numpy_forms():
    # what runs while they are not compiled (a Deferred process, a cold cache): the numpy forms; the other
    # kernels of the module run their Python source
    assert jit.interpreted(records.fill_rows) is records.fill_rows_numpy
    assert jit.interpreted(records.fill_headers) is records.fill_headers_numpy
    assert jit.interpreted(records.group_by_channel).__code__ is records.group_by_channel.py_func.__code__
