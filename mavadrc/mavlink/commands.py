"""Commands to the autopilot and their answers, in the shape of MAVSDK's command sender
(``mavlink_command_sender.cpp``): each COMMAND_LONG is a piece of work, re-sent until a
COMMAND_ACK answers it or its tries run out.

Work is told apart by its key: the command, the system and component it goes to, and, for
MAV_CMD_SET_MESSAGE_INTERVAL and MAV_CMD_REQUEST_MESSAGE, its first parameter (the message it is
about), so that asking for two messages' rates waits on two answers.  An ACK names only the
command: it answers the oldest unanswered work of that command, and only if it comes from the
system and component that work was sent to; one from elsewhere is ignored and counted
(``wrong_source``), as is one that finds no work waiting (``unmatched``: a repeated answer, as
PX4 may send, or not ours).

Two decisions differ from MAVSDK, to keep the companion's behaviour as it was:

* a command with the key of one still waiting replaces it and is sent at once (MAVSDK queues
  the new one until the first is answered or gives up); the first is no longer re-sent by
  :meth:`CommandSender.poll` and gets no answer, and an ACK goes to the newer one;
* work of one command with different keys is sent at once, side by side (MAVSDK sends one work
  of a command id at a time); the vehicle answers them in the order they arrive, so an ACK goes
  to the oldest one waiting.
"""

import time

from mavadrc.mavlink.dialect import M

RESULT_NAMES = {v: k for k, v in vars(M).items() if k.startswith("MAV_RESULT_")
                and isinstance(v, int)}
COMMAND_NAMES = {v: k for k, v in vars(M).items() if k.startswith("MAV_CMD_")
                 and isinstance(v, int)}
#: a command that got no answer after all its tries (not a MAV_RESULT)
TIMEOUT = -1

#: commands whose every answer the user sees (all others are shown when not ACCEPTED)
ANNOUNCED = (M.MAV_CMD_DO_SET_MODE, M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_NAV_LAND,
             M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
#: commands told apart by their first parameter too (the message they are about), as MAVSDK does
KEYED_BY_PARAM1 = (M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAV_CMD_REQUEST_MESSAGE)


def result_name(result):
    if result == TIMEOUT:
        return "no answer"
    if result is None:
        return "waiting"
    return RESULT_NAMES.get(result, str(result)).replace("MAV_RESULT_", "")


def command_name(cmd):
    return COMMAND_NAMES.get(cmd, str(cmd))


def message_name(msgid):
    """MAVLink's name of a message id ("DISTANCE_SENSOR"), or "message N" if the dialect has
    none."""
    cls = M.mavlink_map.get(int(msgid))
    return cls.msgname if cls is not None else f"message {int(msgid)}"


def work_name(cmd, param1=None):
    """A command as the user reads it, with what it is about: "MAV_CMD_SET_MESSAGE_INTERVAL
    (DISTANCE_SENSOR)" for a command keyed by the message it asks for."""
    name = command_name(cmd)
    if cmd in KEYED_BY_PARAM1 and param1 is not None:
        return f"{name} ({message_name(param1)})"
    return name


class Command:
    """One COMMAND_LONG until the vehicle answers it, as MAVSDK's command sender does: sent
    through ``send(target_system, target_component, command, confirmation, *params)`` at once,
    re-sent after ``timeout`` s without an answer, ``tries`` times in all; an IN_PROGRESS answer
    gives it longer.  ``result`` is the vehicle's MAV_RESULT, :data:`TIMEOUT`, or None while
    it waits."""

    IN_PROGRESS_S = 3.0

    def __init__(self, send, cmd, params, target_system=0, target_component=1, timeout=0.5,
                 tries=3):
        self._send_long = send
        self.cmd = cmd
        self.params = [float(v) for v in params] + [0.0] * (7 - len(params))
        self.target_system = target_system
        self.target_component = target_component
        self.timeout = timeout
        self.tries = tries
        self.sent = 0
        self.result = None
        self.ack = None
        self.acked_wall = None  # time.monotonic() of the final answer
        self._due = 0.0
        self._send()

    @property
    def key(self):
        """(command, target system, target component, param1 or None): what tells work apart."""
        return (self.cmd, self.target_system, self.target_component,
                self.params[0] if self.cmd in KEYED_BY_PARAM1 else None)

    def _send(self):
        self.sent += 1
        self._due = time.monotonic() + self.timeout
        self._send_long(self.target_system, self.target_component, self.cmd, self.sent - 1,
                        *self.params)

    @property
    def done(self):
        return self.result is not None

    @property
    def accepted(self):
        return self.result == M.MAV_RESULT_ACCEPTED

    def sent_to(self, system, component):
        """Whether this command went to ``system``/``component`` (0 in its target: any)."""
        return self.target_system in (0, system) and self.target_component in (0, component)

    def answered(self, ack):
        self.ack = ack
        if ack.result == M.MAV_RESULT_IN_PROGRESS:
            self._due = time.monotonic() + self.IN_PROGRESS_S
            return
        self.result = ack.result
        self.acked_wall = time.monotonic()

    def poll(self, now=None):
        """Re-send when an answer is overdue; give up (TIMEOUT) after the last try."""
        if self.result is not None:
            return
        now = time.monotonic() if now is None else now
        if now < self._due:
            return
        if self.sent >= self.tries:
            self.result = TIMEOUT
            self.acked_wall = now
            return
        self._send()

    def __repr__(self):
        return f"<{command_name(self.cmd)} {result_name(self.result)}>"


class CommandSender:
    """The work queue of commands sent and waiting for their answers.

    ``send(target_system, target_component, command, confirmation, *params)`` puts a
    COMMAND_LONG on the wire; ``own_system()`` is the system id we speak as (an ACK addressed to
    another system answers someone else); ``announce(severity, text)`` tells the user of the
    answers worth telling (:data:`ANNOUNCED` ones, and any not ACCEPTED)."""

    def __init__(self, send, own_system, announce):
        self._send = send
        self._own_system = own_system
        self._announce = announce
        # command id (in the order first sent) -> {key: the latest Command of that key}
        self._work = {}
        self.wrong_source = 0  # ACKs of a waiting command from where it was not sent
        self.unmatched = 0  # ACKs that found no command of theirs waiting

    def send(self, cmd, params, target_system, target_component=M.MAV_COMP_ID_AUTOPILOT1,
             timeout=0.5, tries=3):
        """Send a COMMAND_LONG and queue it as work; returns its :class:`Command` (poll it, or
        read its result as the answer comes)."""
        c = Command(self._send, cmd, params, target_system, target_component, timeout=timeout,
                    tries=tries)
        group = self._work.setdefault(cmd, {})
        for key in [k for k, w in group.items() if w.done]:
            del group[key]
        group.pop(c.key, None)  # replaced: its answer, to come, is the newer one's
        group[c.key] = c
        return c

    @property
    def works(self):
        """{key: Command} of the work queued (finished work may linger until the next send)."""
        return {k: c for group in self._work.values() for k, c in group.items()}

    def poll(self, now=None):
        """Re-send every command whose answer is overdue; give up those out of tries."""
        for group in list(self._work.values()):
            for c in list(group.values()):
                c.poll(now)

    def on_ack(self, ack):
        """Hand a COMMAND_ACK of the vehicle to the work it answers; returns that
        :class:`Command`, or None when the ACK answers none of ours."""
        if ack.target_system not in (0, self._own_system()) or \
                ack.target_component not in (0, M.MAV_COMP_ID_ONBOARD_COMPUTER):
            return None  # an answer to someone else's command
        waiting = [c for c in self._work.get(ack.command, {}).values() if not c.done]
        src = (ack.get_srcSystem(), ack.get_srcComponent())
        c = next((c for c in waiting if c.sent_to(*src)), None)
        if c is None:
            if waiting:
                self.wrong_source += 1
            else:
                self.unmatched += 1  # a repeated answer (PX4 may answer twice), or not ours
            return None
        c.answered(ack)
        if ack.result not in (M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_IN_PROGRESS) or \
                ack.command in ANNOUNCED and ack.result == M.MAV_RESULT_ACCEPTED:
            self._announce(M.MAV_SEVERITY_INFO if ack.result == M.MAV_RESULT_ACCEPTED
                           else M.MAV_SEVERITY_WARNING,
                           f"{work_name(ack.command, c.params[0])}: {result_name(ack.result)}")
        return c
