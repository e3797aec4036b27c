"""The companion's supervisor, sample gate, link bookkeeping and PX4 event decoding, as pure
pieces (no vehicle): the table of conditions and actions, how samples are taken and counted."""

import math
import struct
import time

import numpy as np
import pytest

from mavadrc.mavlink import px4_events as E
from mavadrc.mavlink.commands import TIMEOUT, Command
from mavadrc.errors import LinkError
from mavadrc.mavlink.timesync import TimeSync
from mavadrc.mavlink.transport import parse_url
from mavadrc.mission.config import Safety
from mavadrc.mavlink.samples import Sample, SampleGate
from mavadrc.flight.supervisor import (GIVE_UP, HOLD_THEN_LAND, LAND, RULES, WATCH, Supervisor)


def sup(**kw):
    return Supervisor(Safety(**kw), 0.5)


# --- the table -----------------------------------------------------------------------------------


def test_actions_only_escalate_and_every_reason_is_kept_in_order():
    s = sup()
    assert s.report("interrupted", "Ctrl-C") == HOLD_THEN_LAND
    assert s.report("breach", "geofence") == LAND  # more severe: taken
    assert s.report("link", "loss") is None  # less severe than land: no change
    assert s.report("unreachable", "gone") == GIVE_UP
    assert s.report("stale", "telemetry") is None
    assert s.reasons == ["Ctrl-C", "geofence", "loss", "gone", "telemetry"]
    assert s.action == GIVE_UP


def test_watching_the_pilot_is_below_any_landing_we_command():
    s = sup()
    assert s.report("left_control", "pilot took over") == WATCH
    assert s.report("stale", "telemetry lost") == LAND
    assert RULES["left_control"] < RULES["interrupted"] < RULES["stale"] < RULES["unreachable"]


def test_a_repeated_reason_is_kept_once():
    s = sup()
    s.report("stale", "telemetry lost")
    s.report("stale", "telemetry lost")
    assert s.reasons == ["telemetry lost"]


def sample(pos, vel=(0.0, 0.0, 0.0)):
    return Sample(0.0, np.array(pos, dtype=float), np.array(vel, dtype=float))


@pytest.mark.parametrize("pos, vel, words", [
    ((0, 0, -1), (0, 0, 0), None),
    ((6, 0, -1), (0, 0, 0), "geofence breach at north 6.0 m"),
    ((0, -6, -1), (0, 0, 0), "geofence breach"),
    ((0, 0, -11), (0, 0, 0), "altitude limit breach at 11.0 m"),
    ((0, 0, -1), (3, 4, 0), "speed limit breach at 5.0 m/s"),
])
def test_breach_checks(pos, vel, words):
    s = sup(geofence_north=(-5, 5), geofence_east=(-5, 5), altitude_max=10.0, max_speed=4.0)
    why = s.breach(sample(pos, vel), np.zeros(3))
    assert (why is None) if words is None else (words in why)


def test_stale_counts_from_the_last_sample_or_our_answer():
    s = sup()
    assert s.stale(10.0, 9.6, 0.0) is None
    assert "telemetry lost" in s.stale(10.0, 9.4, 0.0)
    assert s.stale(10.0, 9.0, 9.7) is None  # a lockstep vehicle waits on our answer


# --- samples -------------------------------------------------------------------------------------


def feed(gate, times_ms, pos=(0.0, 0.0, 0.0)):
    return [gate.accept(ms, pos, (0.0, 0.0, 0.0)) for ms in times_ms]


def test_late_duplicate_and_nonfinite_samples_are_dropped_and_counted():
    g = SampleGate(0.01)
    out = feed(g, [10, 20, 20, 15, 30])
    assert [s is not None for s in out] == [True, True, False, False, True]
    assert g.duplicate == 1 and g.late == 1
    assert g.accept(40, (math.nan, 0, 0), (0, 0, 0)) is None
    assert g.accept(50, (0, 0, 0), (0, math.inf, 0)) is None
    assert g.nonfinite == 2 and g.dropped == 4
    s = g.accept(60, (0, 0, 0), (0, 0, 0))
    assert s.dt == pytest.approx(0.03)  # from the last accepted sample: the gap is seen


def test_every_missing_sample_is_counted_against_the_period():
    g = SampleGate(0.01)
    ms = [k * 10 for k in range(1, 202) if k % 20 != 0]  # 10 of 201 lost: 5 %
    feed(g, ms)
    assert g.missing == 10
    assert g.loss() == pytest.approx(10 / 201, abs=0.002)
    assert g.longest_gap == pytest.approx(0.02)
    assert g.recent_loss() == pytest.approx(0.05, abs=0.01)


def test_an_estimator_on_its_own_clock_is_not_a_loss():
    """PX4 SIH's estimator ticks every 8 ms: a 100 Hz stream carries samples 8 and 16 ms apart
    (measured on PX4 SITL), 10 ms on average; nothing is missing."""
    g = SampleGate(0.01)
    t, ms = 0, []
    for k in range(500):
        t += 16 if k % 4 == 3 else 8
        ms.append(t)
    feed(g, ms)
    assert g.missing <= 1 and g.recent_loss() < 0.01
    assert g.achieved_rate() == pytest.approx(100.0, rel=0.01)


def test_a_half_rate_stream_is_measured():
    g = SampleGate(0.01)
    feed(g, range(0, 2000, 20))
    assert g.achieved_rate() == pytest.approx(50.0)
    assert g.loss() == pytest.approx(0.5, abs=0.01)
    g.restart(0.02)
    feed(g, range(2000, 4000, 20))


def test_samples_out_of_order_are_told_from_samples_lost():
    """A jittery link delivers some samples behind newer ones: they are dropped, counted among
    the samples missed, and said as out of order, not as lost (behind PX4 SIH through 20 ms of
    jitter, 12 % of the samples came so where the link lost 5.6 %, and the console had said
    "17 % of the samples lost")."""
    import random

    from mavadrc.mavlink.samples import missed_text
    from mavadrc.flight.supervisor import Supervisor

    rng = random.Random(3)
    sent = [k * 10 for k in range(1, 1001)]
    kept = [ms for ms in sent if rng.random() > 0.05]  # 5 % lost
    arrival = sorted(kept, key=lambda ms: ms + 20.0 * rng.random())  # up to 20 ms of jitter
    g = SampleGate(0.01)
    out = feed(g, arrival)
    dropped = sum(s is None for s in out)
    assert g.out_of_order == dropped == g.late
    # uniform jitter over two periods puts about one sample in eight behind its successor
    assert 0.08 < g.out_of_order_share() < 0.17
    assert g.loss() == pytest.approx(g.out_of_order_share() + (1000 - len(kept)) / 1000,
                                     abs=0.01)
    # the samples that came, in order or not: the vehicle's rate less what the link lost
    assert g.arrival_rate() == pytest.approx(100.0 * len(kept) / 1000, rel=0.02)
    assert g.achieved_rate() < 0.9 * g.arrival_rate()
    recent, ooo = g.recent_loss(), g.recent_out_of_order()
    assert 0.05 < ooo < recent < 0.3
    text = Supervisor.link_warning(g)
    assert text == missed_text(recent, ooo)
    assert f"{100 * (recent - ooo):.1f} % lost" in text and "out of order" in text
    # an ordered link with losses says "lost" as before; one that only reorders, no "lost"
    assert missed_text(0.05, 0.0) == "5.0 % of the samples lost"
    assert "lost" not in missed_text(0.12, 0.12)
    # the live line splits them the same way
    import types

    from mavadrc.flight.mission_step import MissionStep

    f = types.SimpleNamespace(gate=g, lockstep=False,
                              link=types.SimpleNamespace(timesync=types.SimpleNamespace(rtts=[])))
    line = MissionStep.link_line(f)
    assert f"lost {100 * (recent - ooo):.1f} %, out of order {100 * ooo:.1f} %" in line
    # a late sample from before the counting restarted is no missing sample of the new count
    g.restart()
    feed(g, [20000, 20010])
    g.accept(19990, (0, 0, 0), (0, 0, 0))
    assert g.out_of_order == 0 and g.late == dropped + 1
    assert g.missing == 0


# --- the link's pieces ---------------------------------------------------------------------------


class FakeMav:
    def __init__(self):
        self.sent = []

    def command_long_send(self, *args):
        self.sent.append(args)


class Ack:
    def __init__(self, result):
        self.result = result


def test_a_command_is_sent_again_until_answered_then_gives_up():
    mav = FakeMav()
    c = Command(mav.command_long_send, 400, [1.0], target_system=1, timeout=0.05, tries=3)
    for _ in range(3):
        time.sleep(0.06)
        c.poll()
    assert len(mav.sent) == 3 and c.result == TIMEOUT
    assert [a[3] for a in mav.sent] == [0, 1, 2]  # confirmation counts the re-sends


def test_in_progress_gives_a_command_longer():
    mav = FakeMav()
    c = Command(mav.command_long_send, 400, [1.0], target_system=1, timeout=0.05, tries=1)
    c.answered(Ack(5))  # MAV_RESULT_IN_PROGRESS
    time.sleep(0.06)
    c.poll()
    assert not c.done
    c.answered(Ack(0))
    assert c.accepted


def test_timesync_offset_and_age():
    ts = TimeSync()
    ts.sent(1_000_000_000)
    # the vehicle's clock read 5.000 s (its boot time) halfway through a 2 ms round trip
    ts.answered(5_000_000_000, 1_000_000_000, 1_002_000_000)
    assert ts.rtts == [pytest.approx(0.002)]
    assert ts.offset_ns == 5_000_000_000 - 1_001_000_000
    # a sample stamped 4.990 s read at our 1.010 s: taken 19 ms before (5.019 - 4.990 s)
    assert ts.age(4990, now_ns=1_010_000_000) == pytest.approx(0.019, abs=1e-9)
    ts.answered(1, 123, 456)  # not ours: ignored
    assert len(ts.rtts) == 1


def test_connection_strings_with_a_bad_port_are_explained():
    with pytest.raises(LinkError, match="not a port number"):
        parse_url("udpin:0.0.0.0:999999")


# --- PX4 events ----------------------------------------------------------------------------------


def test_px4_event_ids_match_the_ids_a_real_px4_sent():
    """Measured on PX4 SITL (SIH, 2026-03 main): landing, then the disarm that followed."""
    assert E.event_id("commander_landing_detected") == 0x19638AC
    assert E.event_id("commander_disarmed_by") == 0x1F46777
    assert E.event_id("commander_arming_check_summary") == 0x1A893E0


def frame(eid, levels, n=53, crc_extra=None):
    from pymavlink.generator.mavcrc import x25crc

    payload = struct.pack("<IIHBBB", eid, 1234, 7, 0, 0, levels) + bytes(40)
    payload = payload[:n]
    head = bytes([0xFD, len(payload), 0, 0, 9, 1, 1, 410 & 0xFF, 410 >> 8, 0])
    crc = x25crc(head[1:] + payload)
    crc.accumulate([E.CRC_EXTRA if crc_extra is None else crc_extra])
    return head + payload + struct.pack("<H", crc.crc)


def test_an_event_frame_is_decoded_and_named():
    ev = E.decode(frame(E.event_id("commander_disarm_denied_not_landed"), 0x62, n=12))
    assert ev.sequence == 7 and ev.time_boot_ms == 1234 and ev.system == 1
    assert E.describe(ev) == "disarming denied: not landed"
    assert E.decode(frame(1, 0, crc_extra=(E.CRC_EXTRA + 1) & 0xFF)) is None  # bad CRC
    unknown = E.decode(frame(0x1ABCDEF, 0x44))
    assert "0x01abcdef" in E.describe(unknown)  # warning level: shown
    assert E.describe(E.decode(frame(0x1ABCDEF, 0x66))) is None  # info level: not


# --- the touchdown speed -------------------------------------------------------------------------


def _descent(times, z_of_t):
    return [(t, z_of_t(t)) for t in times]


def test_touchdown_speed_is_the_fastest_descent_of_the_position_estimate():
    from mavadrc.flight.landing import touchdown_speed
    t = np.arange(0.0, 2.0, 0.02)
    # 0.3 m/s down until 1.5 s, then on the ground: 0.3 m/s, not the instant before it settled
    z = _descent(t, lambda tt: -1.0 + 0.3 * min(tt, 1.5))
    assert touchdown_speed(z) == pytest.approx(0.3, abs=1e-9)
    # a faster last 0.2 s (0.8 m/s) is what counts
    z = _descent(t, lambda tt: -1.0 + 0.3 * min(tt, 1.3) + 0.8 * max(0.0, min(tt, 1.5) - 1.3))
    assert touchdown_speed(z) == pytest.approx(0.8, abs=0.01)
    # climbing or still: zero; a lone sample: zero
    assert touchdown_speed(_descent(t, lambda tt: -1.0 - 0.2 * tt)) == 0.0
    assert touchdown_speed([(0.0, -0.1)]) == 0.0
    # one noisy sample (a 1 cm jump) is averaged over 0.1 s, not read as 0.5 m/s (2 cm in 0.02 s)
    z = _descent(t, lambda tt: -0.5 + (0.01 if abs(tt - 1.0) < 1e-6 else 0.0))
    assert touchdown_speed(z) <= 0.1 + 1e-9
    # uneven intervals (telemetry at a ragged rate) still give the true speed
    tu = np.cumsum(np.r_[0.0, np.tile([0.008, 0.05, 0.016], 30)])
    assert touchdown_speed(_descent(tu, lambda tt: 0.4 * tt)) == pytest.approx(0.4, abs=1e-9)


def test_touchdown_speed_is_judged_where_the_descent_ended_not_where_touchdown_was_seen():
    """PX4 SIH's height estimate climbed at up to 0.2 m/s on the ground after the contact, so
    touchdown was seen seconds later: judged on the last 2 s before that, the speed read 0.00
    for true 0.23-0.35 m/s.  It is judged where the estimate's descent ended."""
    from mavadrc.flight.landing import CONTACT_S, contact_speed, descent_end, touchdown_speed
    t = np.arange(0.0, 8.0, 0.01)
    # 0.5 m/s down, contact at 3 s, then the estimate climbs 0.15 m/s for 5 s on the ground
    z = _descent(t, lambda tt: -1.5 + 0.5 * tt if tt <= 3.0 else -0.15 * (tt - 3.0))
    assert 3.0 - 0.05 <= descent_end(z) <= 3.0  # within DESCENT_END_Z (2 cm) of the lowest
    speed, end = contact_speed(z)
    assert speed == pytest.approx(0.5, abs=0.01) and 2.95 <= end <= 3.0
    assert touchdown_speed([p for p in z if p[0] >= 6.0]) == 0.0  # the old 2 s rule's answer
    # the judgement looks back CONTACT_S only: a fast descent long before the contact (1 m/s
    # until 1.5 s up high, then 0.3 m/s) is not the touchdown speed
    z = _descent(t, lambda tt: -3.0 + tt if tt <= 1.5 else
                 (-1.5 + 0.3 * (tt - 1.5) if tt <= 6.5 else 0.0))
    assert contact_speed(z)[0] == pytest.approx(0.3, abs=0.01)
    assert 6.5 - 1.5 > CONTACT_S
    # noise on the ground within DESCENT_END_Z does not move the end past the contact
    rng = np.random.default_rng(1)
    z = [(tt, zz + (0.005 * rng.standard_normal() if tt > 3.0 else 0.0))
         for tt, zz in _descent(t, lambda tt: -1.5 + 0.5 * min(tt, 3.0))]
    assert descent_end(z) <= 3.0 + 1e-9
    assert contact_speed(z)[0] == pytest.approx(0.5, abs=0.02)
    assert contact_speed([]) == (0.0, None)
