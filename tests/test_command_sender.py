"""The command sender (mavadrc.mavlink.commands), as MAVSDK's: work keyed by command, target and,
for the message-interval and message requests, the message; an answer taken only from the
system and component the command went to; re-sends and timeouts.  A fake transport records what
is sent (no network); one test runs the whole Link over loopback UDP."""

import socket
import time

import pytest

from mavadrc.mavlink.commands import TIMEOUT, CommandSender
from mavadrc.mavlink.dialect import M
from mavadrc.mavlink.link import Link

SMI = M.MAV_CMD_SET_MESSAGE_INTERVAL
ARM = M.MAV_CMD_COMPONENT_ARM_DISARM
LPN = M.MAVLINK_MSG_ID_LOCAL_POSITION_NED
ATT = M.MAVLINK_MSG_ID_ATTITUDE
LATER = 1e9  # a poll time past every deadline: no sleeping


class FakeTransport:
    """What the sender is handed: COMMAND_LONGs recorded, our system id, the user's texts."""

    def __init__(self, own_system=1):
        self.sent = []  # (target_system, target_component, command, confirmation, *params)
        self.texts = []
        self.own_system = own_system

    def sender(self):
        return CommandSender(lambda *a: self.sent.append(a), lambda: self.own_system,
                             lambda sev, text: self.texts.append(text))


def ack(command, result=M.MAV_RESULT_ACCEPTED, src=(1, 1), to=(1, M.MAV_COMP_ID_ONBOARD_COMPUTER)):
    """A COMMAND_ACK from system/component ``src`` addressed to ``to``, as the wire gives it."""
    out = M.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    buf = M.MAVLink_command_ack_message(command, result, 0, 0, *to).pack(out)
    return M.MAVLink(None).decode(bytearray(buf))


@pytest.fixture
def wire():
    return FakeTransport()


def test_an_answer_from_another_system_or_component_is_ignored_and_counted(wire):
    s = wire.sender()
    c = s.send(ARM, [1], target_system=1, target_component=1)
    assert s.on_ack(ack(ARM, src=(1, M.MAV_COMP_ID_CAMERA))) is None  # the vehicle's camera
    assert s.on_ack(ack(ARM, src=(2, 1))) is None  # another vehicle's autopilot
    assert not c.done and s.wrong_source == 2
    assert s.on_ack(ack(ARM, src=(1, 1))) is c
    assert c.accepted and s.wrong_source == 2 and wire.texts == [
        "MAV_CMD_COMPONENT_ARM_DISARM: ACCEPTED"]


def test_an_answer_addressed_to_someone_else_is_not_ours(wire):
    s = wire.sender()
    c = s.send(ARM, [1], target_system=1)
    assert s.on_ack(ack(ARM, to=(1, M.MAV_COMP_ID_MISSIONPLANNER))) is None
    assert s.on_ack(ack(ARM, to=(7, 0))) is None
    assert not c.done and s.wrong_source == 0 and s.unmatched == 0
    assert s.on_ack(ack(ARM, to=(0, 0))) is c  # a broadcast answer is ours


def test_two_message_intervals_are_two_pieces_of_work(wire):
    """SET_MESSAGE_INTERVAL is told apart by its message: each waits for an answer of its own,
    is re-sent on its own, and the answers go to them in the order they were sent."""
    s = wire.sender()
    lpn = s.send(SMI, [LPN, 10_000], target_system=1)
    att = s.send(SMI, [ATT, 20_000], target_system=1)
    assert len(wire.sent) == 2 and len(s.works) == 2
    assert {k[3] for k in s.works} == {LPN, ATT}
    assert s.on_ack(ack(SMI)) is lpn and lpn.accepted and not att.done
    s.poll(time.monotonic() + LATER)  # only the one still waiting goes again
    assert [(a[2], a[3], a[4]) for a in wire.sent[2:]] == [(SMI, 1, ATT)]
    assert s.on_ack(ack(SMI, M.MAV_RESULT_DENIED)) is att and att.result == M.MAV_RESULT_DENIED
    assert s.on_ack(ack(SMI)) is None and s.unmatched == 1  # none waits any more
    # the refusal the user sees names the message it refused (the acceptance is not shown)
    assert wire.texts == ["MAV_CMD_SET_MESSAGE_INTERVAL (ATTITUDE): DENIED"]


def test_a_refused_request_names_its_message_and_an_unknown_one_its_number(wire):
    s = wire.sender()
    s.send(M.MAV_CMD_REQUEST_MESSAGE, [M.MAVLINK_MSG_ID_DISTANCE_SENSOR], target_system=1)
    s.on_ack(ack(M.MAV_CMD_REQUEST_MESSAGE, M.MAV_RESULT_FAILED))
    s.send(SMI, [60999, 1000], target_system=1)
    s.on_ack(ack(SMI, M.MAV_RESULT_UNSUPPORTED))
    assert wire.texts == ["MAV_CMD_REQUEST_MESSAGE (DISTANCE_SENSOR): FAILED",
                          "MAV_CMD_SET_MESSAGE_INTERVAL (message 60999): UNSUPPORTED"]


def test_the_same_request_again_replaces_the_first(wire):
    """A command with the key of one still waiting takes its place (it is sent at once): the
    answer goes to the newer one, and the first is no longer re-sent by the queue."""
    s = wire.sender()
    first = s.send(SMI, [LPN, 10_000], target_system=1)
    second = s.send(SMI, [LPN, 5_000], target_system=1)
    assert len(wire.sent) == 2 and list(s.works.values()) == [second]
    assert s.on_ack(ack(SMI)) is second and second.accepted and not first.done
    s.poll(time.monotonic() + LATER)
    assert len(wire.sent) == 2


def test_other_commands_are_keyed_by_command_and_target_alone(wire):
    s = wire.sender()
    s.send(ARM, [1], target_system=1)
    s.send(ARM, [0], target_system=1)  # disarm replaces arm: one answer names both
    s.send(ARM, [1], target_system=2)
    assert len(s.works) == 2


def test_a_retried_command_is_answered_once(wire):
    """The vehicle answers each send of a command re-sent after a lost answer: the first
    answer settles it, the second finds nothing waiting."""
    s = wire.sender()
    c = s.send(ARM, [1], target_system=1, timeout=0.05, tries=3)
    s.poll(time.monotonic() + LATER)
    assert c.sent == 2 and [a[3] for a in wire.sent] == [0, 1]  # confirmation 0, then 1
    assert s.on_ack(ack(ARM)) is c and c.accepted
    assert s.on_ack(ack(ARM, M.MAV_RESULT_DENIED)) is None  # the answer to the second send
    assert c.accepted and s.unmatched == 1
    assert wire.texts == ["MAV_CMD_COMPONENT_ARM_DISARM: ACCEPTED"]
    s.poll(time.monotonic() + LATER)
    assert len(wire.sent) == 2


def test_no_answer_times_out_after_every_try(wire):
    s = wire.sender()
    c = s.send(SMI, [LPN, 10_000], target_system=1, timeout=0.05, tries=3)
    before = time.monotonic()
    s.poll(before)  # not yet due
    assert c.sent == 1 and not c.done
    for n in (2, 3):
        s.poll(time.monotonic() + LATER)
        assert c.sent == n and not c.done
    s.poll(time.monotonic() + LATER)
    assert c.result == TIMEOUT and c.sent == 3 and len(wire.sent) == 3
    assert c.acked_wall >= before
    assert s.on_ack(ack(SMI)) is None  # a late answer after giving up changes nothing
    assert c.result == TIMEOUT


def test_in_progress_waits_longer_then_the_final_answer_counts(wire):
    s = wire.sender()
    c = s.send(ARM, [1], target_system=1, timeout=0.05, tries=1)
    assert s.on_ack(ack(ARM, M.MAV_RESULT_IN_PROGRESS)) is c and not c.done
    s.poll(time.monotonic() + 0.1)  # past the try's timeout, within IN_PROGRESS_S
    assert not c.done and len(wire.sent) == 1
    assert s.on_ack(ack(ARM)) is c and c.accepted
    assert wire.texts == ["MAV_CMD_COMPONENT_ARM_DISARM: ACCEPTED"]  # IN_PROGRESS is not told


def test_the_link_takes_the_answer_only_from_the_autopilot_over_loopback_udp():
    """The whole Link over loopback UDP: the vehicle's camera answers our arming first, then
    the autopilot; the command is the autopilot's to answer."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    link = Link(f"udpin:127.0.0.1:{port}")
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.settimeout(2.0)
    autopilot = M.MAVLink(None, srcSystem=1, srcComponent=1)
    camera = M.MAVLink(None, srcSystem=1, srcComponent=M.MAV_COMP_ID_CAMERA)

    def say(mav, msg):
        vehicle.sendto(msg.pack(mav), ("127.0.0.1", port))

    try:
        say(autopilot, M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4,
                                                   0, 0, M.MAV_STATE_STANDBY, 3))
        assert link.wait_heartbeat(5.0) is not None
        c = link.command(ARM, 1)
        parser = M.MAVLink(None)
        got = []
        end = time.monotonic() + 5.0
        while not any(m.get_type() == "COMMAND_LONG" for m in got) and time.monotonic() < end:
            got += parser.parse_buffer(vehicle.recv(65535)) or []
        cl = next(m for m in got if m.get_type() == "COMMAND_LONG")
        assert (cl.command, cl.target_system, cl.target_component) == (ARM, 1, 1)
        to = (1, M.MAV_COMP_ID_ONBOARD_COMPUTER)
        say(camera, M.MAVLink_command_ack_message(ARM, M.MAV_RESULT_ACCEPTED, 0, 0, *to))
        end = time.monotonic() + 5.0
        while link.command_sender.wrong_source == 0 and time.monotonic() < end:
            link.recv(0.05)
        assert link.command_sender.wrong_source == 1 and not c.done
        say(autopilot, M.MAVLink_command_ack_message(ARM, M.MAV_RESULT_DENIED, 0, 0, *to))
        end = time.monotonic() + 5.0
        while not c.done and time.monotonic() < end:
            link.recv(0.05)
        assert c.result == M.MAV_RESULT_DENIED
        assert list(link.commands.values()) == [c]
    finally:
        link.close()
        vehicle.close()
