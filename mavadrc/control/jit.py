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


def needs_compiling(*kernels):
    """Whether calling these kernels will compile one: neither compiled in this process nor
    found in numba's on-disk cache for the current source.  A cheap look (numba reads the
    cache's index, a few kB); whatever it cannot tell counts as "will compile"."""
    for k in kernels:
        if not hasattr(k, "py_func") or getattr(k, "overloads", None):
            continue  # plain Python (NUMBA_DISABLE_JIT), or compiled in this process already
        try:
            if not k._cache._cache_file._load_index():
                return True
        except Exception:  # another numba's internals: no way to tell cheaply
            return True
    return False
