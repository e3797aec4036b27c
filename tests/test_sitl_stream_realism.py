"""Streams and link as a real autopilot and a real radio give them (issue 12 items 1 and 2).

The estimator's rate bounds a stream, and each autopilot answers a too-fast request its own way;
a link of limited bandwidth throttles the streams as the autopilot does; and the link model
(latency, jitter, loss, blackouts) applies on the wall clock to the real-time vehicle's
datagrams.  Each docstring names the parameter or default it models and where it lives in the
autopilot's source (PX4-Autopilot and ArduPilot as of 2026).  Timing tests run in real time on a
shared machine: their tolerances are wide, their durations short.
"""

import argparse
import os
import select
import statistics
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl_helpers import Client, free_udp_port, udp_sink
from sim.link_flags import add_link_arguments, link_args, link_from_args
from sim.link_model import LinkModel, Way
from sim.mavlink.realtime import RealtimeLink
from sim.mavlink.link import Stats
from sim.server import SitlServer
from sim.vehicle import SimVehicle

M = mavlink
LPN = M.MAVLINK_MSG_ID_LOCAL_POSITION_NED
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture
def vehicles():
    made = []

    def make(autopilot="px4", lockstep=False, **kw):
        """(server, client on its offboard link, the bound socket its ground-station link
        sends to)"""
        port, gcs = free_udp_port(), udp_sink()
        c = Client(port)  # listening before the vehicle's first heartbeat (t = 0) leaves
        srv = SitlServer(SimVehicle("crazyflie"), autopilot, lockstep=lockstep, bind_offboard=0,
                         bind_gcs=0, offboard_port=port, gcs_port=gcs.getsockname()[1], **kw)
        made.append((srv, c, gcs))
        srv.start()
        c.heartbeat()
        return srv, c, gcs
    yield make
    for srv, c, gcs in made:
        c.close()
        srv.stop()
        gcs.close()


def lpn_rate(c, seconds):
    """LOCAL_POSITION_NED per second over ``seconds``, and the bytes per second of everything
    received, after 0.3 s for the new rate to settle."""
    end = time.monotonic() + 0.3
    while time.monotonic() < end:
        c.c.recv_match(blocking=True, timeout=0.05)
    n = nbytes = 0
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        m = c.c.recv_match(blocking=True, timeout=0.05)
        if m is not None:
            nbytes += len(m.get_msgbuf())
            n += m.get_type() == "LOCAL_POSITION_NED"
    return n / seconds, nbytes / seconds


# --- item 1: the estimator's rate ----------------------------------------------------------------


@pytest.mark.realtime
def test_px4_accepts_a_too_fast_interval_and_streams_at_its_estimator_rate(vehicles):
    """PX4 answers SET_MESSAGE_INTERVAL ACCEPTED whatever the rate
    (MavlinkReceiver::set_message_interval), but LOCAL_POSITION_NED sends each
    vehicle_local_position once, and EKF2 publishes it every EKF2_PREDICT_US (default
    10000 us): asked for 500 Hz it comes at 100 Hz, silently; GET_MESSAGE_INTERVAL reports the
    interval asked (stream->get_interval())."""
    srv, c, _ = vehicles("px4")
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 2000) == M.MAV_RESULT_ACCEPTED
    hz, _ = lpn_rate(c, 1.5)
    assert 80.0 <= hz <= 105.0
    assert not any(m.get_type() == "STATUSTEXT" for m in [c.recv("STATUSTEXT", timeout=0.2)] if m)
    assert c.command(M.MAV_CMD_GET_MESSAGE_INTERVAL, LPN) == M.MAV_RESULT_ACCEPTED
    mi = c.recv("MESSAGE_INTERVAL", cond=lambda m: m.message_id == LPN)
    assert mi.interval_us == 2000


@pytest.mark.realtime
def test_ardupilot_denies_an_interval_faster_than_its_loop_and_says_why(vehicles):
    """ArduCopter streams no message faster than 0.8 x SCHED_LOOP_RATE (default 400 Hz: 3.125 ms,
    GCS_MAVLINK::cap_message_interval); GCS_MAVLINK::set_message_interval works in whole ms
    (truncated) and DENIES a faster request with "Requested rate for message ID %u too fast.
    Increase SCHED_LOOP_RATE" (here cut to STATUSTEXT's 50 characters); 4 ms (250 Hz) is
    served."""
    srv, c, _ = vehicles("ardupilot")
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 3999) == M.MAV_RESULT_DENIED
    text = c.c.messages.get("STATUSTEXT")  # sent just before the answer
    assert text is not None and text.text.startswith("Requested rate for message ID 32 too fast")
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 4000) == M.MAV_RESULT_ACCEPTED
    hz, _ = lpn_rate(c, 1.0)
    assert hz >= 150.0  # 250 Hz asked; a busy machine gets what it can
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 33333) == M.MAV_RESULT_ACCEPTED
    assert srv.links[0].intervals[LPN] == 33000  # whole milliseconds


def test_lockstep_serves_the_interval_asked(vehicles):
    """In lockstep the vehicle's loop runs once per setpoint, at the companion's rate: the
    estimator's bound does not apply (nothing to ask PX4 or ArduPilot; a lockstep choice)."""
    srv, c, _ = vehicles("px4", lockstep=True)
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 2000) == M.MAV_RESULT_ACCEPTED
    assert srv.links[0].intervals[LPN] == 2000


# --- item 1: bandwidth ---------------------------------------------------------------------------


@pytest.mark.realtime
def test_a_57600_radio_throttles_px4_streams_and_the_sample_rate_drops(vehicles):
    """A 57600-baud radio carries 5760 bytes/s; PX4 sizes its streams to half of that unless
    MAV_x_RATE says otherwise (baudrate/20, mavlink module.yaml) and scales every stream's rate
    by one multiplier (Mavlink::update_rate_mult): the link never carries more than its
    bandwidth and LOCAL_POSITION_NED, asked at 100 Hz, comes much slower; a command is still
    answered."""
    srv, c, _ = vehicles("px4", link_bandwidth={"offboard": 5760})
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 10_000) == M.MAV_RESULT_ACCEPTED
    hz, bps = lpn_rate(c, 2.0)
    assert bps <= 5760 * 1.1
    assert 5.0 <= hz <= 60.0
    assert 0.05 <= srv.links[0].rate_mult < 0.6
    assert srv.links[1].line is None  # the ground-station link: UDP, unlimited


@pytest.mark.realtime
def test_ardupilot_streams_wait_for_room_on_a_slow_radio(vehicles):
    """ArduPilot sends a message only when the port has room for it (CHECK_PAYLOAD_SIZE /
    HAVE_PAYLOAD_SPACE, GCS.h) and tries again on a later pass: on a 2880 bytes/s link the
    streams share what the line carries and LOCAL_POSITION_NED falls well below the 100 Hz
    asked; the port's buffer is AP_SERIALMANAGER_MAVLINK_BUFSIZE_TX (256 bytes)."""
    srv, c, _ = vehicles("ardupilot", link_bandwidth={"offboard": 2880})
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 10_000) == M.MAV_RESULT_ACCEPTED
    hz, bps = lpn_rate(c, 2.0)
    assert bps <= 2880 * 1.1
    assert 5.0 <= hz <= 70.0
    assert srv.links[0].line.buffer == 256


# --- item 2: the link model on the wall clock ----------------------------------------------------


def offsets(socks, seconds):
    """{socket: [wall arrival - time_boot_ms]} of the LOCAL_POSITION_NED received on each."""
    parsers = {s: mavlink.MAVLink(None) for s in socks}
    out = {s: [] for s in socks}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ready, _, _ = select.select(socks, [], [], 0.05)
        now = time.monotonic()
        for s in ready:
            data = s.recv(65535)
            for m in parsers[s].parse_buffer(data) or []:
                if m.get_type() == "LOCAL_POSITION_NED":
                    out[s].append(now - m.time_boot_ms / 1e3)
    return out


@pytest.mark.realtime
def test_samples_arrive_late_by_the_latency(vehicles):
    """The link model's down latency (sim.link_model.Way.latency_s; e.g. a telemetry radio's
    20-100 ms) delays every sample on the modelled link: against the ground-station link of the
    same vehicle (perfect, same clocks), LOCAL_POSITION_NED arrives 80 ms later, within a
    shared machine's noise; an up latency delays the command's answer by as much."""
    model = LinkModel(Way(latency_s=0.08), Way(latency_s=0.05))
    srv, c, gcs = vehicles("px4", link=model, link_seed=3)
    ask = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    gcs.sendto(ask.command_long_encode(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, LPN, 20_000,
                                       0, 0, 0, 0, 0).pack(ask),
               ("127.0.0.1", srv.local_ports["gcs"]))
    t0 = time.monotonic()
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 20_000) == 0
    rtt = time.monotonic() - t0
    while select.select([gcs], [], [], 0)[0]:  # what came before the question is not measured
        gcs.recv(65535)
    got = offsets([c.c.port, gcs], 1.5)
    late = statistics.median(got[c.c.port]) - statistics.median(got[gcs])
    assert len(got[gcs]) >= 30 and len(got[c.c.port]) >= 30
    assert late == pytest.approx(0.08, abs=0.02)
    assert 0.125 <= rtt <= 0.4
    assert srv.stats.link_delayed_down > 50 and srv.stats.link_delayed_up >= 1


@pytest.mark.realtime
def test_about_the_fraction_asked_is_lost(vehicles):
    """Loss (sim.link_model.Way.loss) drops each datagram with its probability: of the 100 Hz
    samples (one datagram each), about a quarter never arrive (binomial, n ~ 150: a few
    standard deviations of slack)."""
    srv, c, _ = vehicles("px4", link=LinkModel(Way(loss=0.25)), link_seed=11)
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, LPN, 10_000) == 0
    c.recv("LOCAL_POSITION_NED")
    stamps = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.5:
        m = c.recv("LOCAL_POSITION_NED", timeout=0.2)
        if m is not None:
            stamps.append(m.time_boot_ms)
    sent = (stamps[-1] - stamps[0]) / 10 + 1
    assert 1 - len(stamps) / sent == pytest.approx(0.25, abs=0.1)
    assert srv.stats.link_lost_down > 20


class FakeLink:
    def __init__(self):
        self.sock = SimpleNamespace(sendto=lambda buf, peer: self.sent.append(buf))
        self.sent = []


def decisions(seed, n, model):
    link, stats = FakeLink(), Stats()
    wall = [0.0]
    r = RealtimeLink(link, model, seed, 0, stats, lambda: 0.0, lambda *a: None,
                     wall=lambda: wall[0])
    out = []
    for i in range(n):
        before = len(r._out), len(link.sent)
        r.send(b"x", ("127.0.0.1", 1))
        out.append("lost" if (len(r._out), len(link.sent)) == before else
                   round(r._out[-1][0], 9) if len(r._out) > before[0] else 0.0)
        r._out.clear()
    return out, stats


def test_the_link_decides_the_same_way_for_the_same_seed_and_leaves_the_vehicle_draws_alone():
    """The draws come from a generator of the link's own, per link and direction, seeded from
    --seed: the same datagrams meet the same fate for the same seed, the loss is the fraction
    asked and the delays latency + U(0, jitter); the vehicle's sensor noise is the same with
    and without a link model."""
    model = LinkModel(Way(latency_s=0.02, jitter_s=0.01, loss=0.1))
    a, stats = decisions(5, 20000, model)
    b, _ = decisions(5, 20000, model)
    c, _ = decisions(6, 20000, model)
    assert a == b and a != c
    assert stats.link_lost_down / 20000 == pytest.approx(0.1, abs=0.01)
    kept = np.array([d for d in a if d != "lost"])
    assert kept.min() >= 0.02 and kept.max() <= 0.03
    assert kept.mean() == pytest.approx(0.025, abs=5e-4)

    def noise(with_link):
        v = SimVehicle("crazyflie", seed=5, sensors={"noise": {"position": 0.01}, "latency_s": 0})
        out = []
        for _ in range(20):
            if with_link:
                decisions(5, 10, model)
            v.step(0.01)
            out.append(v.reported().position.copy())
        return np.array(out)
    assert np.array_equal(noise(False), noise(True))


@pytest.mark.realtime
def test_a_blackout_cuts_both_ways_for_its_span(vehicles):
    """A blackout ([start_s, duration_s] of vehicle time, sim.link_model.LinkModel.blackouts):
    no datagram reaches the companion inside it, and a command sent inside it is never
    answered (it does not reach the vehicle); the link comes back after it."""
    srv, c, _ = vehicles("px4", link=LinkModel(blackouts=((1.0, 1.2),)))
    arrivals = []
    end = time.monotonic() + 3.0
    sent_cmd = False
    commands_before = None
    while time.monotonic() < end and srv.time < 2.6:
        m = c.c.recv_match(blocking=True, timeout=0.02)
        if m is not None:
            arrivals.append(srv.time)
        if not sent_cmd and srv.time > 1.3:
            commands_before = srv.stats.commands
            c.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            sent_cmd, sent_at = True, srv.time
    arrivals = np.array(arrivals)
    assert ((arrivals > 0.3) & (arrivals < 0.98)).sum() > 50
    assert ((arrivals > 1.03) & (arrivals < 2.17)).sum() == 0
    assert (arrivals > 2.25).sum() > 20
    assert sent_cmd and sent_at < 2.1
    assert srv.stats.commands == commands_before and srv.stats.link_dark_up >= 1
    assert not srv.vehicle.armed
    assert srv.stats.link_dark_down > 100


# --- options -------------------------------------------------------------------------------------


def parse(argv):
    return link_from_args(add_link_arguments(argparse.ArgumentParser()).parse_args(argv))


def test_the_link_options_parse_and_go_back_into_options():
    model, on, bandwidth = parse(["--link-down", "latency=0.02,jitter=0.01,loss=0.05",
                                  "--link-up", "loss=0.01", "--link-blackout", "12:2",
                                  "--link-blackout", "30:0.5", "--link-on", "both",
                                  "--link-bandwidth", "5760", "--link-bandwidth", "gcs=1200"])
    assert model == LinkModel(Way(0.02, 0.01, 0.05), Way(loss=0.01), ((12.0, 2.0), (30.0, 0.5)))
    assert on == ("offboard", "gcs") and bandwidth == {"offboard": 5760.0, "gcs": 1200.0}
    again, on2, bw2 = parse(link_args(model, "both", 5760))
    assert again == model and on2 == on and bw2 == {"offboard": 5760.0, "gcs": 5760.0}
    assert parse([]) == (None, ("offboard",), {})
    assert link_args(None) == [] and link_args(LinkModel()) == []


@pytest.mark.parametrize("argv, flag", [
    (["--link-down", "latncy=0.1"], "--link-down"),
    (["--link-up", "loss=1.5"], "--link-up"),
    (["--link-down", "latency=fast"], "--link-down"),
    (["--link-blackout", "12"], "--link-blackout"),
    (["--link-blackout", "12:0"], "--link-blackout"),
    (["--link-on", "radio"], "--link-on"),
    (["--link-bandwidth", "0"], "--link-bandwidth"),
    (["--link-bandwidth", "telem=5760"], "--link-bandwidth"),
])
def test_a_bad_link_option_is_one_line_naming_it(argv, flag):
    with pytest.raises(SystemExit) as e:
        parse(argv)
    text = str(e.value)
    assert text.startswith(flag + ":") and "\n" not in text


@pytest.mark.realtime
def test_mavadrc_sitl_says_what_the_link_did_at_exit_and_refuses_a_bad_option():
    """`python -m sim` with a link model: the drops and delays in one line at exit; a bad
    option: one line on stderr, before anything is compiled or bound."""
    env = dict(os.environ, PYTHONPATH=ROOT)
    bad = subprocess.run([sys.executable, "-m", "sim", "--link-down", "loss=2"], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0
    assert bad.stderr.strip().splitlines() == ["--link-down: loss must be in [0, 1] (got 2.0)"]
    listen, gcs = udp_sink(), udp_sink()
    try:
        ok = subprocess.run([sys.executable, "-m", "sim", "--duration", "1.5",
                             "--offboard-port", str(listen.getsockname()[1]),
                             "--gcs-port", str(gcs.getsockname()[1]), "--bind-offboard", "0",
                             "--bind-gcs", "0", "--link-down", "latency=0.01,loss=0.5"],
                            cwd=ROOT, env=env, capture_output=True, text=True, timeout=90)
    finally:
        listen.close()
        gcs.close()
    assert ok.returncode == 0, ok.stderr
    last = ok.stdout.strip().splitlines()[-1]
    assert last.startswith("mavadrc sitl: link down: ") and " lost, " in last


def test_the_embedded_vehicle_gets_the_missions_link():
    """`mavadrc fly` starts `python -m sim` for the mission: its ``sim: {link:}`` goes along."""
    from mavadrc.flight.embedded import link_options

    model = LinkModel(Way(latency_s=0.03), blackouts=((5.0, 1.0),))
    assert link_options(SimpleNamespace(link=model)) == link_args(model)
    assert link_options(SimpleNamespace(link=None)) == []
    assert link_options(SimpleNamespace()) == []
