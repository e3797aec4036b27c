"""Which system on the link is the autopilot flown, and what arrives from it.

One autopilot is flown: the first autopilot heartbeat heard names it, or ``sysid`` picks it when
several systems are heard.  Messages of any other system are dropped and counted.  Over udpin
the chosen system must also keep speaking from the address it was first heard from.  The
autopilot's frames are counted, and the frames lost on the way read off the gaps in their
MAVLink sequence numbers.
"""

import collections

from mavadrc.errors import LinkError
from mavadrc.mavlink.dialect import M

#: sequence numbers jumped over that a late frame may still fill in (a reordering link)
SKIPPED_KEPT = 64


def count_sequence(last, seq, skipped):
    """(the newest sequence number, frames to count lost) after a frame numbered ``seq`` where
    ``last`` was the newest (None: the first).  A jump ahead counts the numbers jumped over as
    lost and keeps them in ``skipped`` (a bounded deque); a frame behind the newest one that
    fills one of them in was late, not lost, and is taken back (-1); any other frame behind is
    a repeat (0).  A jittery link reorders frames: counted as gaps alone, 5 % of the samples
    lost read as 23 % of the frames."""
    if last is None:
        return seq, 0
    gap = (seq - last - 1) & 0xFF
    if gap >= 128:  # behind the newest
        if seq in skipped:
            skipped.remove(seq)
            return last, -1
        return last, 0
    for k in range(1, gap + 1):
        skipped.append((last + k) & 0xFF)
    # what is now half the sequence behind could only be matched by a later lap's number
    while skipped and (seq - skipped[0]) & 0xFF >= 128:
        skipped.popleft()
    return seq, gap


class Sources:
    """The autopilot chosen among the systems heard on ``url``, and the bookkeeping of what
    comes from it.

    ``wanted_sysid`` picks the system (None: the first autopilot heard).  ``speak_as(sysid)``
    is called when one is chosen (the companion then speaks as that system);
    ``answer_to(addr)`` when, over udpin (``by_address``), the chosen autopilot's address is
    first heard (the link then answers it only).
    """

    def __init__(self, url, wanted_sysid=None, by_address=False, speak_as=None, answer_to=None):
        self.url = url
        self.wanted_sysid = wanted_sysid
        self.by_address = by_address
        self._speak_as = speak_as or (lambda sysid: None)
        self._answer_to = answer_to or (lambda addr: None)
        self.target_system = 0
        self.autopilot = None  # "px4" or "ardupilot" once chosen
        self.systems_heard = set()
        self.other_system = 0  # messages of other systems dropped
        # udpin: the address the chosen autopilot speaks from, and any other address that
        # speaks as the same system (another vehicle with its id: _one_source)
        self.source = None
        self.other_sources = {}  # address -> messages dropped
        self.frames_received = 0
        self.frames_lost = 0
        self._last_seq = None
        # sequence numbers jumped over and not yet seen (count_sequence)
        self._skipped = collections.deque(maxlen=SKIPPED_KEPT)

    def admit(self, msg, t):
        """Whether ``msg`` (of type ``t``) comes from the chosen autopilot's system (choosing it
        from an autopilot heartbeat when none is yet); counts what is dropped and the
        autopilot's frames."""
        src = msg.get_srcSystem()
        if t == "HEARTBEAT" and msg.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1 \
                and msg.autopilot != M.MAV_AUTOPILOT_INVALID:
            self.systems_heard.add(src)
            if self.target_system == 0 and self.wanted_sysid in (None, src):
                self._choose(msg)
        if self.target_system == 0 or src != self.target_system:
            if self.target_system != 0:
                self.other_system += 1
            return False
        if self.by_address and not self._one_source(getattr(msg, "_from", None)):
            return False
        if msg.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1:
            self._count_seq(msg.get_seq())
        return True

    def _choose(self, hb):
        self.target_system = hb.get_srcSystem()
        self._speak_as(self.target_system)
        if hb.autopilot == M.MAV_AUTOPILOT_PX4:
            self.autopilot = "px4"
        elif hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.autopilot = "ardupilot"
        else:
            raise LinkError(f"the autopilot of system {self.target_system} on {self.url} is "
                            f"neither PX4 nor ArduPilot (MAV_AUTOPILOT {hb.autopilot}); "
                            "mavadrc flies those two")

    def _one_source(self, frm):
        """Over udpin, whether a message of the chosen system comes from the address it was
        first heard from (and answered there).  Another address speaking as the same system is
        a second vehicle with its id (two SITLs on one port, two radios): MAVLink cannot tell
        them apart, and answering whoever spoke last sent the setpoints to both in turn and
        flew the loop on both vehicles' positions mixed.  Its messages are dropped and counted
        (``other_sources``); a flight refuses to arm while one is heard."""
        if frm is None or frm == self.source:
            return True
        if self.source is None:
            self.source = frm
            self._answer_to(frm)  # answer the chosen autopilot only
            return True
        self.other_sources[frm] = self.other_sources.get(frm, 0) + 1
        return False

    def sources_text(self):
        """What ``other_sources`` means, for a refusal or a warning (None when empty)."""
        if not self.other_sources:
            return None
        others = ", ".join(f"{a}:{p}" for a, p in self.other_sources)
        return (f"two vehicles speak as system {self.target_system} on {self.url}: "
                f"{self.source[0]}:{self.source[1]} (flown) and {others} "
                f"({sum(self.other_sources.values())} messages of the other dropped); MAVLink "
                "cannot tell them apart, so setpoints could reach either; stop one, or give "
                "them different system ids")

    def _count_seq(self, seq):
        """Frames lost on the way: gaps in the autopilot's MAVLink sequence numbers
        (:func:`count_sequence`)."""
        self.frames_received += 1
        self._last_seq, lost = count_sequence(self._last_seq, seq, self._skipped)
        self.frames_lost += lost

    def frame_loss(self):
        n = self.frames_received + self.frames_lost
        return self.frames_lost / n if n else 0.0
