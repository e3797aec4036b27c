"""Loaded (by PYTHONPATH) into a ``mavadrc compare`` the tests interrupt: widens a race of
CPython 3.11's process pool at interpreter exit so that it is hit every time.

After Ctrl-C the pool's manager thread sees the terminated workers and closes its wake-up pipe;
at exit ``concurrent.futures.process._python_exit`` checks that pipe is open, then writes to it.
Here the manager closes 0.2 s late and the exit writes 0.4 s after its check: unless the
companion waited for the manager before exiting, the write meets a closed pipe and the exit
prints "OSError: handle is closed" (about 1 run in 50 on a loaded machine without the delays).
"""

import time

import concurrent.futures.process as _pool

if hasattr(_pool, "_ExecutorManagerThread") and hasattr(_pool, "_ThreadWakeup"):
    _terminate_broken = _pool._ExecutorManagerThread.terminate_broken

    def _late_terminate_broken(self, cause):
        time.sleep(0.2)
        return _terminate_broken(self, cause)

    def _slow_wakeup(self):
        if not self._closed:
            if _pool._global_shutdown:
                time.sleep(0.4)
            self._writer.send_bytes(b"")

    _pool._ExecutorManagerThread.terminate_broken = _late_terminate_broken
    _pool._ThreadWakeup.wakeup = _slow_wakeup
