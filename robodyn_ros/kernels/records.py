"""MCAP message records of a recorder's batch in compiled loops (:mod:`robodyn_ros.recording.mcap_sink`).

A batch of periods is a few hundred messages; doing their record headers and their chunk's
message index entries with numpy takes a few dozen array calls per batch, each of which costs
more than the loop over the messages does compiled. The bytes are those of ``mcap.Writer``
writing the messages one at a time (the recording tests compare files byte for byte).
``tf_values_many`` does the same for the ``/tf`` numbers of a batch (:meth:`robodyn_ros.tf.TfTree.transform_values`).

numba is optional (README, "Dependencies"): without it these loops run as plain Python (the
same operations, so the same bytes, slower), so that a recording never needs it. The two that
write every byte of a batch, :func:`fill_rows` and :func:`fill_headers`, run as numpy instead
whenever they are not compiled (:func:`fill_rows_numpy`, :func:`fill_headers_numpy`: without numba,
and on a cold cache until the compiler child has them, :func:`.jit.interpreted_by`): the same bytes,
written by a few array calls per batch rather than a Python loop over every byte (an A1's first
run spent 4 of its 18 s there). ``test/test_records.py`` compares the three forms byte for byte.
"""
from __future__ import annotations

import math

import numpy as np

from .jit import NUMBA, interpreted_by, njit   # njit: numba's, or without numba the functions as they are

_JIT = dict(cache=True, nogil=True, _nrt=True)


@njit(**_JIT)
def _put(buf, at, x, nbytes):
    for b in range(nbytes):
        buf[at + b] = (x >> (8 * b)) & 0xFF


@njit(**_JIT)
def fill_headers(records, offsets, sizes, channels, log_times, sequence):
    """Write each message's 31-byte record header into the gap left for it at ``offsets[k]``:
    opcode 5 (message), record length (what follows opcode and length: ``sizes[k] - 9``), channel
    id, sequence number (per channel: ``sequence[channel] + 1``, updated), log and publish time
    (both ``log_times[k]``), little-endian as the MCAP spec lays them out."""
    for k in range(offsets.shape[0]):
        a = offsets[k]
        c = channels[k]
        s = sequence[c] + 1
        sequence[c] = s
        records[a] = 5
        _put(records, a + 1, sizes[k] - 9, 8)
        _put(records, a + 9, c, 2)
        _put(records, a + 11, s, 4)
        _put(records, a + 15, log_times[k], 8)
        _put(records, a + 23, log_times[k], 8)


@njit(**_JIT)
def group_by_channel(channels, log_times, offsets, base, entries, group_channel, group_start):
    """The message index entries ``(log_time, base + offset)`` of n messages grouped by channel:
    groups in order of each channel's first message, entries in message order within a group
    (what n calls of ``mcap.Writer.add_message`` append to the chunk's message indexes).

    entries (n, 2) uint64, group_channel (n,), group_start (n + 1,) int64 are filled; returns
    the number of groups g (group i: channel ``group_channel[i]``, entries
    ``group_start[i]:group_start[i + 1]``).
    """
    n = channels.shape[0]
    nc = 0
    for k in range(n):
        if channels[k] + 1 > nc:
            nc = channels[k] + 1
    group_of = np.full(nc, -1, dtype=np.int64)
    count = np.zeros(n, dtype=np.int64)
    g = 0
    for k in range(n):
        c = channels[k]
        if group_of[c] < 0:
            group_of[c] = g
            group_channel[g] = c
            g += 1
        count[group_of[c]] += 1
    group_start[0] = 0
    for i in range(g):
        group_start[i + 1] = group_start[i] + count[i]
    fill = group_start[:g].copy()
    for k in range(n):
        i = group_of[channels[k]]
        p = fill[i]
        entries[p, 0] = log_times[k]
        entries[p, 1] = base + offsets[k]
        fill[i] = p + 1
    return g


@njit(**_JIT)
def fill_rows(template, bits, value_col, value_at, times, stamp_at, stamp_of, out):
    """K periods' records from their row template: ``out[k] = template`` with the float64 of
    column ``value_col[i]`` of ``bits`` (K, n) (the numbers as int64 bit patterns) at byte
    ``value_at[i]``, and a ``builtin_interfaces/Time`` (int32 sec, uint32 nanosec) of
    ``times[k, stamp_of[i]]`` (int ns) at byte ``stamp_at[i]``, little-endian."""
    for k in range(out.shape[0]):
        row = out[k]
        row[:] = template
        for i in range(value_col.shape[0]):
            _put(row, value_at[i], bits[k, value_col[i]], 8)
        for i in range(stamp_at.shape[0]):
            t = times[k, stamp_of[i]]
            sec = t // 1_000_000_000
            _put(row, stamp_at[i], sec & 0xFFFFFFFF, 4)
            _put(row, stamp_at[i] + 4, t - sec * 1_000_000_000, 4)


def _little_endian(x, nbytes):
    """The low ``nbytes`` bytes of each integer of x, little-endian, as uint8 (..., nbytes): what
    :func:`_put` writes (two's complement for a negative one)."""
    x = np.asarray(x)
    x = np.ascontiguousarray(x, dtype='<u8' if x.dtype.kind == 'u' else '<i8')
    return x.view(np.uint8).reshape(x.shape + (8,))[..., :nbytes]


@interpreted_by(fill_headers)
def fill_headers_numpy(records, offsets, sizes, channels, log_times, sequence):
    """:func:`fill_headers` by array calls (the same bytes; what runs while it is not compiled)."""
    n = offsets.shape[0]
    if n == 0:
        return
    order = np.argsort(channels, kind='stable')
    c = channels[order]
    first = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])            # each channel's first message, in order
    rank = np.arange(n) - np.repeat(first, np.diff(np.r_[first, n]))  # messages of its channel before it
    s = np.empty(n, dtype=np.int64)
    s[order] = sequence[c] + rank + 1
    last = order[np.r_[first[1:] - 1, n - 1]]                        # each channel's last message
    sequence[channels[last]] = s[last]
    head = np.empty((n, 31), dtype=np.uint8)
    head[:, 0] = 5
    head[:, 1:9] = _little_endian(sizes - 9, 8)
    head[:, 9:11] = _little_endian(channels, 2)
    head[:, 11:15] = _little_endian(s, 4)
    head[:, 15:23] = _little_endian(log_times, 8)
    head[:, 23:31] = head[:, 15:23]
    records[np.asarray(offsets, dtype=np.int64)[:, None] + np.arange(31)] = head


@interpreted_by(fill_rows)
def fill_rows_numpy(template, bits, value_col, value_at, times, stamp_at, stamp_of, out):
    """:func:`fill_rows` by array calls (the same bytes; what runs while it is not compiled)."""
    out[:] = template
    if value_col.shape[0]:
        out[:, value_at[:, None] + np.arange(8)] = _little_endian(bits[:, value_col], 8)
    if stamp_at.shape[0]:
        t = times[:, stamp_of]
        sec = t // 1_000_000_000
        out[:, stamp_at[:, None] + np.arange(4)] = _little_endian(sec & 0xFFFFFFFF, 4)
        out[:, stamp_at[:, None] + np.arange(4, 8)] = _little_endian(t - sec * 1_000_000_000, 4)


if not NUMBA:   # (no compiled form: the recorder calls these)
    fill_headers, fill_rows = fill_headers_numpy, fill_rows_numpy


@njit(error_model='numpy', **_JIT)
def tf_values_many(revolute, src, axis, p_tree, q_tree, R_tree, positions, out, first):
    """``/tf`` of K publications: ``out[k, first + j] = (x, y, z, qx, qy, qz, qw)`` of moving joint j
    at ``theta = positions[k, src[j]]``, by the float operations of ``TfTree.transforms`` in its
    order: a revolute joint ``q_tree ⊗ (a sin θ/2, cos θ/2)`` at ``p_tree``, a prismatic one
    ``p_tree + R_tree a d`` with ``q_tree`` (the recordings test compares the bytes with that path).
    """
    K = positions.shape[0]
    for k in range(K):
        for j in range(src.shape[0]):
            th = positions[k, src[j]]
            o = out[k, first + j]
            if revolute[j]:
                half = 0.5 * th
                s = math.sin(half)
                c = math.cos(half)
                bx, by, bz = axis[j, 0] * s, axis[j, 1] * s, axis[j, 2] * s
                qx, qy, qz, qw = q_tree[j, 0], q_tree[j, 1], q_tree[j, 2], q_tree[j, 3]
                o[0], o[1], o[2] = p_tree[j, 0], p_tree[j, 1], p_tree[j, 2]
                o[3] = qw * bx + c * qx + qy * bz - qz * by
                o[4] = qw * by + c * qy + qz * bx - qx * bz
                o[5] = qw * bz + c * qz + qx * by - qy * bx
                o[6] = qw * c - qx * bx - qy * by - qz * bz
            else:
                dx, dy, dz = axis[j, 0] * th, axis[j, 1] * th, axis[j, 2] * th
                for r in range(3):
                    o[r] = p_tree[j, r] + R_tree[j, r, 0] * dx + R_tree[j, r, 1] * dy + R_tree[j, r, 2] * dz
                for r in range(4):
                    o[3 + r] = q_tree[j, r]
