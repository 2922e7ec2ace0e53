"""The value strings of a diagnostics status (messages.diagnostic_pairs / _fmt), written out by
hand: the recorder's fast path and the message dicts both use them, so comparing the two
paths cannot catch a wrong string."""
import math

import numpy as np

from robodyn_ros import messages as M


def test_diagnostic_pairs_value_strings():
    values = {'steps': 3000, 'big': 12345678901234567890, 'neg': -7, 'np_int': np.int64(42), 'flag': True,
              'np_flag': np.bool_(False), 'energy': 95.33381234, 'tenth': 0.1, 'whole': 3.0, 'tiny': 1e-300,
              'negz': -0.0, 'nan': math.nan, 'inf': -math.inf, 'np_float': np.float64(2.5),
              'np_f32': np.float32(0.1), 'np_nan': np.float64('nan'), 'name': 'rk4', 'unknown': None}
    assert M.diagnostic_pairs(values) == [
        ('steps', '3000'), ('big', '12345678901234567890'), ('neg', '-7'), ('np_int', '42'), ('flag', 'true'),
        ('np_flag', 'false'), ('energy', '95.33381234'), ('tenth', '0.1'), ('whole', '3.0'), ('tiny', '1e-300'),
        ('negz', '-0.0'), ('nan', 'nan'), ('inf', '-inf'), ('np_float', '2.5'),
        ('np_f32', '0.10000000149011612'), ('np_nan', 'nan'), ('name', 'rk4'), ('unknown', 'None')]
