"""What every robodyn process does at start-up before its own work (robodyn_ros/__init__.py)."""
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.processes

#: a child that imports the package and numpy (which loads OpenBLAS and starts its worker threads), waits
#: 0.3 s (a spinning worker's 2^28 cycles are about 0.1 s), then prints the setting it sees and the CPU
#: clock ticks (utime + stime, /proc) of every thread but the main one: numpy's and scipy's BLAS workers
_CHILD = r'''
import os, time
import robodyn_ros, numpy, scipy.linalg
time.sleep(0.3)
pid = os.getpid()
ticks = 0
for tid in os.listdir(f'/proc/{pid}/task'):
    if int(tid) != pid:
        with open(f'/proc/{pid}/task/{tid}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        ticks += int(fields[11]) + int(fields[12])
print(os.environ.get('OPENBLAS_THREAD_TIMEOUT'), robodyn_ros.SET_BLAS_TIMEOUT, ticks,
      len(os.listdir(f'/proc/{pid}/task')) - 1)
'''


def _child(env):
    # two threads whatever the machine (OpenBLAS starts one worker beside the calling thread), whatever
    # the environment the suite runs in says of threads
    env = {k: v for k, v in env.items() if k not in ('OMP_NUM_THREADS', 'GOTO_NUM_THREADS')}
    env['OPENBLAS_NUM_THREADS'] = '2'
    out = subprocess.run([sys.executable, '-c', _CHILD], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    value, was_set, ticks, threads = out.stdout.split()
    return value, was_set == 'True', int(ticks), int(threads)


def test_blas_workers_sleep_at_once():
    """Importing robodyn_ros before numpy: OpenBLAS's workers sleep at once instead of busy-waiting
    about 0.1 s of a core each (2 ticks of 10 ms allowed for the threads' start on a loaded machine)."""
    env = {k: v for k, v in os.environ.items() if k != 'OPENBLAS_THREAD_TIMEOUT'}
    value, was_set, ticks, threads = _child(env)
    assert (value, was_set) == ('4', True)
    assert threads >= 1, 'no BLAS worker thread started: nothing was measured'
    assert ticks <= 2, f'the {threads} BLAS worker threads used {ticks} ticks of CPU at start-up'


def test_blas_timeout_of_the_environment_is_kept():
    """A value the user set stays as it is, and the package says it did not set it."""
    env = {**os.environ, 'OPENBLAS_THREAD_TIMEOUT': '9'}
    value, was_set, _, _ = _child(env)
    assert (value, was_set) == ('9', False)
