"""What the user of `mavadrc fly` sees: messages, the vehicle's words and the live progress line.

A terminal gets one progress line rewritten in place; a pipe or a file gets a line every 5 s, so
a log of a flight stays readable.

The console is never a reason to drop a vehicle: a companion flies with its output on a terminal
that can hang up (an SSH session lost), in a pipe whose reader can quit (``| head``) or on a full
disk.  A write that fails (:class:`Guarded`) silences the console for the rest of the run, the
failed text and everything after it goes to the ``fallback`` (the flight's companion.log), and
the flight goes on as if nothing had happened.
"""

import contextlib
import os
import signal
import sys
import threading
import time


class Guarded:
    """A text stream whose writes never raise: the first that fails (an ``OSError``: a broken
    pipe, a terminal hung up, a full disk) makes it quiet for good.  Its file descriptor, if it
    has one, is pointed at the null device then, so what Python flushes at exit does not fail
    either.  ``lost``: None, or what went wrong; ``fallback(text)`` receives what could not be
    written and all text written after."""

    def __init__(self, out, fallback=None):
        self.out = out
        self.fallback = fallback
        self.lost = None
        self._pending = []  # written since the last flush that went through

    def write(self, text):
        if self.lost is None:
            try:
                self.out.write(text)
                self._pending.append(text)
                return
            except OSError as exc:
                self._lose(exc)
        self._fall(text)

    def flush(self):
        if self.lost is None:
            try:
                self.out.flush()
                self._pending.clear()
            except OSError as exc:
                self._lose(exc)

    def isatty(self):
        try:
            return self.lost is None and self.out.isatty()
        except (AttributeError, OSError, ValueError):
            return False

    def _lose(self, exc):
        self.lost = f"{type(exc).__name__}: {exc}"
        pending, self._pending = "".join(self._pending), []
        self._fall(pending)  # written, but never out of the buffer
        try:
            fd = self.out.fileno()
        except (AttributeError, OSError, ValueError):
            return
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(null, fd)
            finally:
                os.close(null)
        except OSError:
            pass

    def _fall(self, text):
        if self.fallback is not None and text.strip():
            try:
                self.fallback(text)
            except OSError:
                pass


def guarded(out, fallback=None):
    """``out`` as a :class:`Guarded` stream (itself if it already is one; ``fallback`` set)."""
    if isinstance(out, Guarded):
        if fallback is not None:
            out.fallback = fallback
        return out
    return Guarded(out, fallback)


def counted(n, noun):
    """``n`` and ``noun``, plural unless n is 1: '1 seed', '3 seeds'."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


@contextlib.contextmanager
def ticking(say, what, every=5.0, enabled=True):
    """No silent wait: while the body runs (a compile, a fit), ``say(f"{what} ({n} s)")``
    every ``every`` s from a thread of its own; nothing if it ends sooner, or if not
    ``enabled`` (no thread then)."""
    if not enabled:
        yield
        return
    done = threading.Event()
    t0 = time.monotonic()

    def tick():
        while not done.wait(every):
            say(f"{what} ({time.monotonic() - t0:.0f} s)")

    ticker = threading.Thread(target=tick, name="ticking", daemon=True)
    ticker.start()
    try:
        yield
    finally:
        done.set()
        ticker.join()


class Steps:
    """Progress through ``total`` steps of ``unit`` (runs, evaluations, measurements): a tqdm
    bar on a terminal (rate and time left), a plain line at most every ``every`` s otherwise
    (a log or a pipe gets lines, not carriage returns), nothing when not ``enabled``.
    ``describe(text)`` names the step under way."""

    def __init__(self, total, unit, out=None, enabled=True, every=5.0, desc=None):
        self.total, self.unit, self.done = total, unit, 0
        self.out = out if out is not None else sys.stderr
        self.enabled, self.every, self.desc = enabled, every, desc
        self.t0 = self._last = time.monotonic()
        self._bar = None
        if enabled and self.out.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, unit=f" {unit}s", file=self.out, desc=desc,
                             mininterval=0.2, dynamic_ncols=True, leave=True)

    def describe(self, text):
        self.desc = text
        if self._bar is not None:
            self._bar.set_description_str(text)
        elif self.enabled:
            self._line(force=True)

    def step(self, n=1):
        self.done += n
        if self._bar is not None:
            self._bar.update(n)
            if self.done >= self.total:
                self.close()
        elif self.enabled:
            self._line(force=self.done >= self.total)

    def _line(self, force=False):
        now = time.monotonic()
        if not force and now - self._last < self.every:
            return
        self._last = now
        rate = self.done / max(now - self.t0, 1e-9)
        what = f"{self.desc}: " if self.desc else ""
        self.out.write(f"{what}{self.done}/{counted(self.total, self.unit)}, "
                       f"{rate:.1f} {self.unit}s/s\n")
        self.out.flush()

    def close(self):
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class Console:
    """Writes to ``out`` (guarded: :class:`Guarded`; its text goes to ``fallback`` once ``out``
    fails); ``progress=False`` drops the live line (messages still go out)."""

    def __init__(self, out=sys.stdout, progress=True, fallback=None):
        self.out = guarded(out, fallback)
        self.progress_on = progress
        self._tty = self.out.isatty()
        self._last_print = 0.0
        self._last_line = 0.0
        self._bar = None  # the live line on a terminal: a tqdm bar over the mission's time

    @property
    def lost(self):
        """None while the console is written; else why it is not (the first failed write)."""
        return self.out.lost

    def say(self, text):
        if self._bar is not None and self.out.lost is None:
            self._bar.clear()  # the live line gives way; the next progress() draws it again
        elif self.progress_on and self._tty and self.out.lost is None:
            self.out.write("\r\033[K")
        self.out.write(text + "\n")
        self.out.flush()

    def vehicle(self, text):
        """A message in the vehicle's own words (STATUSTEXT, a command's answer)."""
        self.say(f"  vehicle: {text}")

    def progress(self, segment, t, duration, error, link=None):
        """The live line: segment, mission time, current 3-D error and the link's state
        (``link()`` gives its text); at most 5 per second."""
        now = time.monotonic()
        if not self.progress_on or now - self._last_print < 0.2:
            return
        self._last_print = now
        # padded, never cut: 'transit to thesis_spiral' is read whole
        head = f"{segment:<18} t {t:6.1f}/{duration:.0f} s  error {error:6.3f} m"
        tail = f"  {link()}" if link is not None else ""
        if self.out.lost is not None:
            return  # the live line is no record: not written to the fallback
        if self._tty:
            self._draw(head, tail, t, duration)
            return
        k = min(1.0, t / duration) if duration > 0 else 1.0
        line = f"{head}  [{'#' * int(20 * k)}{'-' * (20 - int(20 * k))}]{tail}"
        if now - self._last_line >= 5.0:
            self._last_line = now
            self.out.write(line + "\n")
            self.out.flush()

    def _draw(self, head, tail, t, duration):
        """The live line on a terminal: tqdm's bar over the mission's time, with the time left
        at the pace flown (real time, or faster in lockstep)."""
        fmt = "{desc}  |{bar:20}| {remaining} left" + tail.replace("{", "{{").replace("}", "}}")
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(total=max(float(duration), 1e-9), file=self.out, leave=False,
                             dynamic_ncols=True, mininterval=0.0, desc=head, bar_format=fmt)
        self._bar.bar_format = fmt
        self._bar.set_description_str(head, refresh=False)
        self._bar.n = min(max(float(t), 0.0), self._bar.total)
        self._bar.refresh()

    def close(self):
        """Take the live line off the terminal (the flight's last lines follow)."""
        if self._bar is not None:
            if self.out.lost is None:
                self._bar.close()
            self._bar = None


class Terminated(KeyboardInterrupt):
    """A signal that asks the companion to stop (SIGTERM: ``kill``, a service manager, a
    container stopping), taken as Ctrl-C is: in the air, hold, then land; a second one leaves
    the vehicle to its autopilot.  ``signum``, ``signame``."""

    def __init__(self, signum):
        self.signum = int(signum)
        self.signame = signal.Signals(self.signum).name
        super().__init__(self.signame)


#: the exit status of a command the user interrupted (128 + SIGINT), as shells expect
EXIT_INTERRUPTED = 130


def interrupt_reason(exc):
    """What ended a flight interrupted by ``exc`` (a KeyboardInterrupt), as summary.json's
    ``aborted`` says it."""
    if isinstance(exc, Terminated):
        return f"terminated by {exc.signame}"
    return "interrupted by the user"


def interrupt_word(exc):
    """``exc`` (a KeyboardInterrupt) in one word or three, for "... : nothing flew"."""
    return f"terminated by {exc.signame}" if isinstance(exc, Terminated) else "interrupted"


def interrupt_exit_status(exc):
    """The exit status ``exc`` (a KeyboardInterrupt) ends the command with: 130 for Ctrl-C, 128
    plus the signal's number for a signal, as shells report them."""
    return 128 + exc.signum if isinstance(exc, Terminated) else EXIT_INTERRUPTED


class FlightSignals:
    """The signals a flight answers, while installed (:meth:`install`, main thread only;
    :meth:`restore` puts the old handlers back, and does nothing if none were installed):
    SIGTERM raises :class:`Terminated` where Ctrl-C would raise KeyboardInterrupt, and SIGHUP
    (the terminal gone) no longer ends the process: ``on_hangup()`` is called and the flight
    goes on (the console then fails and goes quiet)."""

    def __init__(self, on_hangup=None):
        self.on_hangup = on_hangup
        self._old = {}

    def install(self):
        if threading.current_thread() is not threading.main_thread():
            return
        wanted = [(signal.SIGTERM, self._term)]
        if hasattr(signal, "SIGHUP"):
            wanted.append((signal.SIGHUP, self._hup))
        for sig, handler in wanted:
            self._old[sig] = signal.signal(sig, handler)

    def restore(self):
        old, self._old = self._old, {}
        for sig, handler in old.items():
            signal.signal(sig, handler)

    @staticmethod
    def _term(signum, frame):
        raise Terminated(signum)

    def _hup(self, signum, frame):
        if self.on_hangup is not None:
            self.on_hangup()
