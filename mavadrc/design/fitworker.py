"""The input model's fit in a process of its own, beside a flight flown in real time.

The fit of the doublets (:func:`mavadrc.design.gains.fit_and_make`: a grid and a Nelder-Mead search,
then the controller made with it and its delay margins) is one to two seconds of Python and
numba kernels.  Made in a thread beside the control loop, it shared the interpreter's lock with
the loop: on PX4 SIH the samples' age rose from ~0 to 0.21-0.27 s as the second fit (the drag
learnt) ended, a moment before the thesis spiral began, and the 1 Hz swing that followed made
the spiral's worst errors (0.155-0.224 m).  In a process of its own the loop shares only the
cores with it.

The process is ``python -m mavadrc.design.fitworker``, started when the flight starts (it loads what
a fit uses long before the doublets end), fed pickled calls on its stdin and answering on its
stdout.  Started so, rather than by :mod:`multiprocessing`, it never runs the caller's own
script again (``spawn`` imports the main module: a script that flies without an
``if __name__ == "__main__"`` guard would fly again in the child).  Where it cannot be started,
or dies, the call is made in the calling thread as before, and :attr:`FitWorker.where` says so.
"""

import os
import pickle
import subprocess
import sys
import threading


class FitWorker:
    """Calls made in one child process, one at a time."""

    def __init__(self):
        self.where = "process"
        self.why_not = None  # why the calls are made in the calling thread instead
        self._proc = None
        self._lock = threading.Lock()  # one call at a time on the pipe
        try:
            # the caller's import path, so whatever it pickles by name is found
            here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
            env = dict(os.environ, PYTHONPATH=os.pathsep.join([here] + [p for p in sys.path
                                                                         if p]))
            self._proc = subprocess.Popen([sys.executable, "-m", "mavadrc.design.fitworker"],
                                          stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          env=env)
        except OSError as exc:
            self._in_thread(exc)

    def _in_thread(self, exc):
        self.where = "thread"
        self.why_not = f"{type(exc).__name__}: {exc}"
        self.close()

    def call(self, fn, *args):
        """``fn(*args)`` (a module-level function; it, its arguments and its result pickled),
        made in the child process while the calling thread waits on a pipe, without holding
        the interpreter; in the calling thread where there is no process.  An exception
        raised by ``fn`` is raised here."""
        with self._lock:
            proc = self._proc
            if proc is not None:
                try:
                    _send(proc.stdin, pickle.dumps((fn, args), pickle.HIGHEST_PROTOCOL))
                    ok, value = pickle.loads(_receive(proc.stdout))
                except (OSError, EOFError, pickle.UnpicklingError) as exc:
                    self._in_thread(exc)
                else:
                    if ok:
                        return value
                    raise value
        return fn(*args)

    def close(self):
        """Stop the process (a call still running is abandoned)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            proc.stdin.close()
        except OSError:
            pass
        try:
            proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stdout.close()


def _send(pipe, data):
    pipe.write(len(data).to_bytes(8, "little") + data)
    pipe.flush()


def _receive(pipe):
    """One message's bytes (EOFError: the pipe closed)."""
    head = pipe.read(8)
    if len(head) < 8:
        raise EOFError("the pipe closed")
    n = int.from_bytes(head, "little")
    data = pipe.read(n)
    if len(data) < n:
        raise EOFError("the pipe closed within a message")
    return data


def serve(inp, out):
    """The child's loop: calls read from ``inp`` until it closes, each answered on ``out`` with
    (True, result) or (False, the exception raised, or the one unpickling the call raised)."""
    while True:
        try:
            data = _receive(inp)
        except EOFError:
            return
        try:
            fn, args = pickle.loads(data)
            answer = (True, fn(*args))
        except Exception as exc:  # the caller's to raise
            answer = (False, exc)
        try:
            reply = pickle.dumps(answer, pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # an answer that cannot travel says why
            reply = pickle.dumps((False, RuntimeError(f"the answer could not be pickled: "
                                                      f"{type(exc).__name__}: {exc}")))
        _send(out, reply)


def _main():
    # the answers get stdout to themselves: whatever else prints goes to stderr
    out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    inp = sys.stdin.buffer
    import importlib

    from mavadrc.design.identify import load_fitting

    importlib.import_module(f"{__package__}.gains")  # fit_and_make's module, imported now
    load_fitting()
    serve(inp, out)


if __name__ == "__main__":
    _main()
