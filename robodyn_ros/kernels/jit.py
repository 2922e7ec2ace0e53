"""``njit`` for the kernels that must also run without numba: numba's when it can be imported, else
a decorator that leaves the function as it is, so the same source runs as plain Python (slower,
the same operations).

The tree algorithms (:mod:`.tree`), the PFL law (:mod:`.pfl`), the command profiles
(:mod:`.profiles`) and the recorder's loops (:mod:`.records`) are written once, here in the
kernels; the Python code that needs them without the compiled path (``ROBODYN_BACKEND=numpy``
keeps numba's compiled versions; a machine without numba runs these plain) calls them the same way.
"""
from __future__ import annotations

try:
    from numba import njit
    NUMBA = True
except ImportError:   # no numba: the kernels below run as Python functions
    NUMBA = False

    def njit(*args, **_):
        """``@njit(...)`` / ``@njit`` without numba: the function itself."""
        if len(args) == 1 and callable(args[0]):
            return args[0]
        return lambda f: f

__all__ = ['njit', 'NUMBA']
