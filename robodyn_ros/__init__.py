"""robodyn_ros: robot dynamics for ROS 2, exact and measured (README.md).

Importing the package sets one process-wide default before numpy loads OpenBLAS:
``OPENBLAS_THREAD_TIMEOUT=4`` (unless the environment already sets it). OpenBLAS starts a worker
thread per core when it loads, and each worker busy-waits 2^28 cycles (about 0.1 s of a core) for
work before it sleeps; numpy and scipy each bring an OpenBLAS, so every process that imports them
burned about 0.2 s of CPU on a 2-core machine at start-up, beside its own work (the package does its
linear algebra in its compiled kernels, not in BLAS). At 4 the workers sleep at once (2^4 cycles);
a threaded BLAS call still uses them, and wakes them from sleep. The arithmetic does not change
(the number of threads and the kernels are OpenBLAS's own). Child processes inherit it.
"""
import os as _os

#: True when this import set ``OPENBLAS_THREAD_TIMEOUT`` (the environment did not): benchmarks of peers'
#: processes take it out again, so that those run as their users would run them
SET_BLAS_TIMEOUT = 'OPENBLAS_THREAD_TIMEOUT' not in _os.environ
_os.environ.setdefault('OPENBLAS_THREAD_TIMEOUT', '4')
