"""The one place the numeric kernels are compiled.

Every kernel in mavadrc is a plain function over floats and float64 arrays, compiled here with
numba.  ``NUMBA_DISABLE_JIT=1`` turns the decorator into a no-op, so the same source runs as plain
Python for debugging and coverage.
"""

from numba import njit

#: Decorator for scalar/array kernels: compiled once, cached on disk beside the source.
jit = njit(cache=True, nogil=True)
