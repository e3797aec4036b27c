"""What the user of `mavadrc fly` sees: messages, the vehicle's words and the live progress line.

A terminal gets one progress line rewritten in place; a pipe or a file gets a line every 5 s, so
a log of a flight stays readable.
"""

import sys
import time


def counted(n, noun):
    """``n`` and ``noun``, plural unless n is 1: '1 seed', '3 seeds'."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


class Console:
    """Writes to ``out``; ``progress=False`` drops the live line (messages still go out)."""

    def __init__(self, out=sys.stdout, progress=True):
        self.out = out
        self.progress_on = progress
        self._tty = out.isatty() if hasattr(out, "isatty") else False
        self._last_print = 0.0
        self._last_line = 0.0

    def say(self, text):
        if self.progress_on and self._tty:
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
        k = min(1.0, t / duration) if duration > 0 else 1.0
        bar = "#" * int(20 * k) + "-" * (20 - int(20 * k))
        # padded, never cut: 'transit to thesis_spiral' is read whole
        line = f"{segment:<18} t {t:6.1f}/{duration:.0f} s  error {error:6.3f} m  [{bar}]"
        if link is not None:
            line += f"  {link()}"
        if self._tty:
            self.out.write("\r\033[K" + line)
            self.out.flush()
        elif now - self._last_line >= 5.0:
            self._last_line = now
            self.out.write(line + "\n")
            self.out.flush()
