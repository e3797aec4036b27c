"""The in-process fast path: a mission flown on the vehicle's compiled kernels."""
