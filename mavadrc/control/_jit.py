"""The one place the numeric kernels are compiled.

Every kernel in mavadrc is a plain function over floats and float64 arrays, compiled here with
numba.  ``NUMBA_DISABLE_JIT=1`` turns the decorator into a no-op, so the same source runs as plain
Python for debugging and coverage.
"""

from numba import njit

#: Decorator for scalar/array kernels: compiled once, cached on disk beside the source.
jit = njit(cache=True, nogil=True)

#: The same for the small hot kernels a step calls on every sample (the nominal-step paths of the
#: observers, the TD, PID): inlined into their callers in numba's IR, so a control step costs no
#: call layers (their off-nominal paths live in separate, not inlined, kernels).
jit_inline = njit(cache=True, nogil=True, inline="always")
