"""Waiting on the vehicle: a command's answer, confirmed by a heartbeat newer than it (a lost
answer is settled by the heartbeat), and a lost command sent again."""

import time

from mavadrc.mavlink.commands import TIMEOUT
from mavadrc.mavlink.dialect import M


class Confirm:
    """The command a phase waits on (``cmd``) and the heartbeat that confirms it."""

    #: how often a command that went unanswered after every try is sent again in one phase
    ASK_AGAIN = 3

    def __init__(self, link, notices):
        self.link = link
        self.notices = notices
        self.cmd = None  # the command the phase waits on
        self.tries = 0
        self.unheard = False  # the phase's command went unanswered after every try
        self.asked_again = 0  # how often the phase's command was sent again for that
        self.since = None  # judge state only from heartbeats after this wall time
        self.hb_request_wall = 0.0

    def awaiting(self):
        """Whether the flight waits on an answer of the vehicle (a command's, or a heartbeat
        asked for).  In lockstep the vehicle's clock is held meanwhile, so the flight does not
        depend on how fast the answer travels (same seed, same flight)."""
        if self.cmd is not None and not self.cmd.done:
            return True
        return self.hb_request_wall > 0.0 and self.link.heartbeat_since(self.hb_request_wall) is None

    def ask_heartbeat(self):
        """Ask for a heartbeat now instead of waiting up to a second for the next (PX4 sends
        them at 1 Hz)."""
        self.hb_request_wall = time.monotonic()
        self.link.request_message(M.MAVLINK_MSG_ID_HEARTBEAT)

    def fresh(self):
        """The latest heartbeat, if it is newer than the last change the flight asked for."""
        return self.link.heartbeat_since(self.since)

    def ask_again(self, hb, state):
        """Whether to send the phase's command again: it went unanswered after every try, and
        the heartbeat asked for since shows the vehicle ``state`` (the command was lost on the
        way: on a link that loses a fifth of the datagrams each way, three tries are all lost
        once in 125 flights).  At most :attr:`ASK_AGAIN` times a phase."""
        if hb is None or not self.unheard or self.cmd is not None or \
                self.asked_again >= self.ASK_AGAIN:
            return False
        self.unheard = False
        self.asked_again += 1
        self.notices.say(f"{state} by its heartbeat after an unanswered command: sending it "
                         f"again ({self.asked_again} of {self.ASK_AGAIN})")
        return True

    def refused_answer(self, c, what, question):
        """The answer to a command that changes the vehicle's state: accepted, it is to be seen
        in a heartbeat newer than the answer; unanswered, such a heartbeat settles it (both
        asked for now).  Returns whether the vehicle refused."""
        self.cmd = None
        if c.accepted or c.result == TIMEOUT:
            self.ask_heartbeat()
            self.since = c.acked_wall if c.accepted else self.hb_request_wall
            if c.result == TIMEOUT:
                self.notices.say(f"no answer to {what} after {c.sent} tries: asking the vehicle "
                                 f"{question}")
            return False
        return True
