"""What a flight says: its lines on the console, its warnings (kept for summary.json), and the
vehicle's own words."""

import math
import time

#: s within which the vehicle's same words again are counted, not shown (:meth:`Notices.on_text`)
TEXT_QUIET_S = 10.0


class Notices:
    """The flight's console lines and warnings, and the vehicle's texts (``texts``)."""

    def __init__(self, console):
        self.console = console
        self.warnings = []
        self.texts = []
        self.warned = {}  # key: wall time a warning of that key was last said
        self.warned_text = {}  # key: the text warn_once last kept for it
        self._texts_shown = {}  # the vehicle's words: [wall time last shown, times unshown since]

    def say(self, text):
        self.console.say(text)

    def warn_once(self, key, text, every=5.0, latest=False):
        """Say ``text`` as a warning, at most once every ``every`` s for ``key``, and keep it in
        the summary's warnings once; ``latest``: the summary keeps only the latest said for
        ``key`` (a reading that changes as the flight goes on: a faulty link's loss, said every
        5 s, once left eleven "X % of the samples lost" in one summary)."""
        now = time.monotonic()
        if now - self.warned.get(key, -math.inf) >= every:
            self.warned[key] = now
            self.say(f"warning: {text}")
            if latest and key in self.warned_text:
                old = self.warned_text[key]
                self.warnings[self.warnings.index(old)] = text
            elif text not in self.warnings:
                self.warnings.append(text)
            self.warned_text[key] = text

    def on_text(self, severity, text):
        """The vehicle's words, each on the console; the same words again within
        :data:`TEXT_QUIET_S` of their last showing are counted, not shown, and the count is
        said with them next time (PX4, refusing a disarm asked for every second, said "disarming
        denied: not landed" and its answer 18 times each in 18 s)."""
        self.texts.append(text)
        now = time.monotonic()
        shown = self._texts_shown.get(text)
        if shown is not None and now - shown[0] < TEXT_QUIET_S:
            shown[1] += 1
            return
        more = f" (and {shown[1]} times more since)" if shown is not None and shown[1] else ""
        self._texts_shown[text] = [now, 0]
        self.console.vehicle(text + more)

    def because(self):
        """The vehicle's latest words of its own (its reason, as "Disarming denied: not
        landed"), not a command's answer, which the caller names already; "" if none among the
        last three."""
        for text in reversed(self.texts[-3:]):
            if not text.startswith("MAV_CMD_"):
                return f" ({text})"
        return ""
