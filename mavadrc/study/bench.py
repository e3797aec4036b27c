"""`mavadrc bench`: per-call step times of the controllers (and, when present, of the vehicle).

Figures are medians over repeated blocks of calls on this machine; peers (pyadrc, rotorpy) are
measured in the same run so ratios stay meaningful on a shared, noisy machine.  Names carry their
units.  A peer that is not installed has None (null in JSON) for its figures, and the table says
how to install it.
"""

import contextlib
import json
import math
import sys
import time

import numpy as np

from mavadrc.control import PD, AttitudeController, HanADRC, LinearADRC, PositionController
from mavadrc.flight.console import Steps
from mavadrc.flight.embedded import free_udp_port, udp_sink
from sim.bench import median_us

#: the peers measured beside our kernels when installed, and how to install them
PEERS = ("pyadrc", "rotorpy")
PEERS_INSTALL = 'pip install -e ".[bench]" (from the mavadrc checkout)'


def per_call_us(fn):
    """Median over 25 blocks of 2000 calls of the mean time of one call, in microseconds."""
    return median_us(fn, 2000, 25)


def control_figures():
    h = 0.001
    lad = LinearADRC(h=h, b0=1.0, wc=20.0, wo=100.0, u_min=-50.0, u_max=50.0)
    han = HanADRC(h=h, b0=1.0, r0=20.0, r=100.0, c=0.5, h1=10 * h, u_min=-50.0, u_max=50.0)
    pd = PD(h=h, kp=400.0, kd=40.0)
    y = [0.0]

    def step(ctrl):
        def call():
            y[0] = 0.999 * y[0] + 0.001
            ctrl.update(y[0], 1.0, 0.0, 0.0)
        return call

    pos = PositionController("ladrc", h=0.01, hover_thrust=0.5, wc=2.0, wo=10.0)
    pos_han = PositionController("adrc", h=0.01, hover_thrust=0.5, r0=5.0, r=20.0)
    p = np.array([0.1, -0.2, -1.0])
    v = np.zeros(3)
    rp = np.array([0.0, 0.0, -1.0])
    rv = np.zeros(3)
    ra = np.zeros(3)
    att = AttitudeController("ladrc", h=h, inertia=(1.43e-5, 1.43e-5, 2.89e-5), wc=25.0, wo=120.0)
    e = np.array([0.01, -0.02, 0.3])
    w = np.zeros(3)
    er = np.array([0.0, 0.0, 0.3])
    fig = {
        "linear_adrc_step_us": per_call_us(step(lad)),
        "han_adrc_step_us": per_call_us(step(han)),
        "pd_step_us": per_call_us(step(pd)),
        "position_controller_ladrc_step_us": per_call_us(lambda: pos.update(p, v, rp, rv, ra, 0.0)),
        "position_controller_adrc_step_us": per_call_us(
            lambda: pos_han.update(p, v, rp, rv, ra, 0.0)),
        "attitude_controller_ladrc_step_us": per_call_us(lambda: att.update(e, w, er)),
    }
    fig.update(reference_figures())
    fig.update(identify_figures())
    fig.update(fit_beside_loop_figures())
    fig["ratio_reference_sample_over_position_controller_ladrc_step"] = (
        fig["reference_sample_us"] / fig["position_controller_ladrc_step_us"])
    try:
        import pyadrc
    except ImportError:
        fig["pyadrc_statespace_step_us"] = None
        fig["ratio_pyadrc_over_linear_adrc"] = None
    else:
        peer = pyadrc.StateSpace(order=2, delta=h, b0=1.0, w_cl=20.0, k_eso=5.0,
                                 m_lim=(-50.0, 50.0))
        u = [0.0]

        def peer_call():
            y[0] = 0.999 * y[0] + 0.001
            u[0] = peer(y[0], u[0], 1.0)

        fig["pyadrc_statespace_step_us"] = per_call_us(peer_call)
        fig["ratio_pyadrc_over_linear_adrc"] = (fig["pyadrc_statespace_step_us"]
                                                / fig["linear_adrc_step_us"])
    return fig


def reference_figures():
    """The reference a flight samples once to three times a step (the thesis spiral in wind's,
    with its takeoff, transit and land): one time, against the many-times path's cost per
    time over a whole flight's times (:func:`control_figures` sets it beside the LADRC step it
    feeds)."""
    from mavadrc.mission.config import load_mission

    traj, _ = load_mission("thesis_spiral_wind").build_trajectory(np.zeros(3))
    ts = np.linspace(-1.0, traj.duration + 1.0, 2000)
    i = [0]

    def one():
        i[0] = (i[0] + 1) % len(ts)
        traj.sample(ts[i[0]])

    fig = {"reference_sample_us": per_call_us(one),
           "reference_sample_many_per_time_us": median_us(lambda: traj.sample_many(ts), 1, 25)
           / len(ts)}
    fig["ratio_reference_sample_over_sample_many_per_time"] = (
        fig["reference_sample_us"] / fig["reference_sample_many_per_time_us"])
    return fig


def identify_figures():
    """The identification's fit (:mod:`mavadrc.design.identify`): its compiled lags and integral over
    one axis's window (4.2 s of doublets at its 1 ms grid), against scipy.signal.lfilter doing
    the same (what the fit called before, bit for bit the same result), and one whole fit of
    that window (a synthetic plant: two 0.05 s lags, 20 ms dead time, a drifting gust)."""
    from scipy.signal import lfilter

    from mavadrc.design import identify as I

    rng = np.random.default_rng(0)
    x = np.cumsum(rng.standard_normal(4550))
    at = np.arange(350, x.size, 10)
    alpha = I._alpha(0.05)

    def scipy_lags():
        y = x
        for _ in range(I.ORDER):
            y, _ = lfilter([alpha], [1.0, alpha - 1.0], y, zi=[y[0] * (1.0 - alpha)])
        w = np.cumsum(y) * I.FINE_S
        return w[at] - w[350]

    fig = {"identify_lags_us": median_us(
               lambda: I.lagged_change(x, alpha, I.ORDER, at, 350, I.FINE_S), 200, 15),
           "scipy_lfilter_lags_us": median_us(scipy_lags, 200, 15)}
    fig["ratio_scipy_lfilter_over_identify_lags"] = (fig["scipy_lfilter_lags_us"]
                                                     / fig["identify_lags_us"])
    plant = _doublets_plant(rng)
    I.load_fitting()
    t0 = time.perf_counter()
    rec = I.fit_axis(*plant)
    fig["identify_fit_axis_s"] = time.perf_counter() - t0
    if not rec["ok"]:
        raise RuntimeError(f"the bench's plant was not identified: {rec}")
    return fig


def _doublets_plant(rng):
    """One axis of doublets for the fit: u from 0.5 s, seen 20 ms late through two 50 ms lags,
    drag 0.3 /s, a drifting gust, velocity noise 1 cm/s; (t, u, v, start, end)."""
    from mavadrc.design import identify as I
    from mavadrc.mission import identification as MI

    dt = 0.01
    t = np.arange(0.0, 6.0, dt)
    period = 2 * MI.HALF_PERIOD
    phase = (t - 0.5) % period
    u = np.where((t >= 0.5) & (t < 0.5 + 4 * period), np.where(phase < MI.HALF_PERIOD, 2.0, -2.0),
                 0.0)
    fine = np.arange(0.0, 6.0, I.FINE_S)
    a = I.lagged(I._shifted_hold(t, u, fine, 0.02), I._alpha(0.05), I.ORDER)
    v = np.zeros(fine.size)
    for k in range(1, fine.size):
        v[k] = v[k - 1] + (a[k - 1] - 0.3 * v[k - 1] + 0.2 * math.sin(0.9 * fine[k])) * I.FINE_S
    vs = np.interp(t, fine, v) + 0.01 * rng.standard_normal(t.size)
    return t, u, vs, 0.5, 0.5 + 4 * period


def _longest_gap_ms(work, period_s=0.002):
    """The longest pause (ms) of a loop that sleeps ``period_s`` per turn (the control loop
    waiting on its socket) while ``work`` runs in a thread beside it, and what ``work``
    returned."""
    import threading

    done = threading.Event()
    out = []
    th = threading.Thread(target=lambda: (out.append(work()), done.set()))
    last, gap = time.perf_counter(), 0.0
    th.start()
    while not done.is_set():
        time.sleep(period_s)
        now = time.perf_counter()
        gap, last = max(gap, now - last), now
    th.join()
    return 1e3 * gap, out[0]


def fit_beside_loop_figures():
    """The identification a real-time flight makes after its doublets (thesis_spiral_wind's, on
    the bundled Crazyflie in process: the fit and the LADRC made with it, with its margins,
    :func:`~mavadrc.design.gains.fit_and_make`) beside a loop that sleeps 2 ms a turn: the loop's
    longest pause with it in a thread (as flights made it before) and in the fits' own process
    (:mod:`mavadrc.design.fitworker`, started and warmed first), each the worst of three."""
    from mavadrc.design.fitworker import FitWorker
    from mavadrc.design.gains import fit_and_make
    from mavadrc.fast import identify as FI
    from mavadrc.mission.config import load_mission

    m = load_mission("thesis_spiral_wind")
    d, windows = FI.samples_inprocess(FI.identification_mission(m, calm=True), seed=0)
    job = (d, windows, "in the bench", m.controller, "ladrc", 100.0, 0.47, FI.design_lag(m))
    def worst_gap_ms(make):
        gaps = []
        for _ in range(3):
            gap, (rec, ctrl, _, _) = _longest_gap_ms(make)
            if ctrl is None:
                raise RuntimeError(f"the bench's doublets were not identified: {rec}")
            gaps.append(gap)
        return max(gaps)

    fit_and_make(*job)  # its kernels loaded here, as a flight's are before it flies
    fig = {"fit_beside_loop_thread_longest_gap_ms": worst_gap_ms(lambda: fit_and_make(*job))}
    worker = FitWorker()
    try:
        worker.call(fit_and_make, *job)  # the process up and its kernels loaded
        fig["fit_beside_loop_process_longest_gap_ms"] = worst_gap_ms(
            lambda: worker.call(fit_and_make, *job))
        if worker.where != "process":
            raise RuntimeError(f"the fits' process did not start: {worker.why_not}")
    finally:
        worker.close()
    fig["ratio_fit_beside_loop_longest_gap_thread_over_process"] = (
        fig["fit_beside_loop_thread_longest_gap_ms"]
        / fig["fit_beside_loop_process_longest_gap_ms"])
    return fig


def _cpu_seconds(pid):
    """User + system CPU time of a process (Linux /proc), in seconds."""
    import os
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@contextlib.contextmanager
def _sitl_process(*extra):
    """``python -m sim`` as a process of its own for the block: (process, offboard port); its
    ground-station streams go to a port held meanwhile."""
    import subprocess
    port = free_udp_port()
    sink = udp_sink()
    proc = subprocess.Popen([sys.executable, "-m", "sim", "--instance", "20", "--offboard-port",
                             str(port), "--gcs-port", str(sink.getsockname()[1]),
                             "--bind-offboard", "0", "--bind-gcs", "0", *extra],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        yield proc, port
    finally:
        proc.terminate()
        proc.wait(10)
        sink.close()


def _realtime_load(mavutil, seconds, *extra):
    """(clock error %, CPU % of a core) of the bundled vehicle serving in real time for
    ``seconds`` with the server options ``extra``."""
    with _sitl_process(*extra) as (proc, port):
        c = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
        c.wait_heartbeat(timeout=30)
        first = c.recv_match(type="ATTITUDE", blocking=True, timeout=30)
        wall0, boot0, cpu0 = time.monotonic(), first.time_boot_ms, _cpu_seconds(proc.pid)
        last = first
        while time.monotonic() - wall0 < seconds:
            m = c.recv_match(type="ATTITUDE", blocking=True, timeout=1)
            if m is not None:
                last, wall1 = m, time.monotonic()
        cpu1 = _cpu_seconds(proc.pid)
        wall = wall1 - wall0
        c.close()
        return (abs((last.time_boot_ms - boot0) / 1e3 - wall) / wall * 100,
                (cpu1 - cpu0) / wall * 100)


def sitl_figures(realtime_seconds=10.0, lockstep_seconds=10.0):
    """Real-time clock accuracy and CPU load of the bundled vehicle (also with sensor noise and
    a wandering estimate, whose draws it makes at every physics step), and a lockstep closed
    loop.

    Both run the vehicle as its own process (``python -m sim``) and talk to it over loopback
    MAVLink with pymavlink, as a user's script would.
    """
    import os
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    fig = {}
    err, cpu = _realtime_load(mavutil, realtime_seconds)
    fig["sitl_realtime_clock_error_pct"] = err
    fig["sitl_realtime_cpu_pct_of_core"] = cpu
    err, cpu = _realtime_load(mavutil, realtime_seconds, "--noise", "--wander", "0.06")
    fig["sitl_realtime_wander_clock_error_pct"] = err
    fig["sitl_realtime_wander_cpu_pct_of_core"] = cpu
    fig["ratio_sitl_realtime_cpu_wander_over_plain"] = \
        cpu / max(fig["sitl_realtime_cpu_pct_of_core"], 1e-9)

    with _sitl_process("--lockstep", "--lockstep-rate", "100") as (_, port):
        fig["sitl_lockstep_x_realtime"] = _lockstep_hover(mavutil, port, lockstep_seconds)
    return fig


def _serving_load(serve, clock, seconds, settle=0.5):
    """(CPU fraction of one core, simulated over wall seconds) of a serving loop that runs in
    a thread of this process (``serve.start()`` / ``serve.stop()``; ``clock()`` its vehicle
    time), measured over ``seconds`` after ``settle`` seconds."""
    serve.start()
    try:
        time.sleep(settle)
        cpu0, wall0, sim0 = time.process_time(), time.monotonic(), clock()
        time.sleep(seconds)
        cpu1, wall1, sim1 = time.process_time(), time.monotonic(), clock()
    finally:
        serve.stop()
    wall = wall1 - wall0
    return (cpu1 - cpu0) / wall, (sim1 - sim0) / wall


def fleet_figures(seconds=3.0, counts=(1, 10, 30, 60, 100), more=(150, 200, 300), tick=0.004):
    """`mavadrc sitl --count N`: the CPU load of one process serving N vehicles in real time
    with the serving loop at 1/tick Hz (250 Hz; physics at 1 kHz inside) and full telemetry
    (LOCAL_POSITION_NED and ATTITUDE at 100 Hz on each offboard link, the default rest on both
    links), for each N of ``counts`` and then of ``more`` while real time holds; and a
    single-vehicle server measured the same way in the same run, as the peer.

    Real time holds when the vehicles' clock keeps within 1 % of the wall clock and the loop
    needs less than one core.  Every link sends to one bound loopback socket nobody reads (the
    kernel drops what overflows it), so what is measured is the server's own work.
    """
    from sim.fleet import FleetServer
    from sim.mavlink.link import LPN
    from sim.server import SitlServer
    from sim.vehicle import SimVehicle

    sink = udp_sink()
    port = sink.getsockname()[1]

    def servers(n):
        out = []
        for k in range(n):
            s = SitlServer(SimVehicle("crazyflie", seed=k), "px4", k, tick=tick,
                           bind_offboard=0, bind_gcs=0, offboard_port=port, gcs_port=port)
            s.links[0].set_interval(LPN, 10_000, due=0)  # ATTITUDE is at 100 Hz already
            out.append(s)
        return out

    fig = {}
    try:
        single = servers(1)[0]
        cpu1, _ = _serving_load(single, lambda: single.time, seconds)
        fig["sitl_single_250hz_cpu_pct_of_core"] = cpu1 * 100.0
        best = prev = None
        for n in list(counts) + list(more):
            if n in more and best != prev:
                break  # the previous count already lost real time
            fleet = FleetServer(servers(n), tick=tick)
            cpu, speed = _serving_load(fleet, lambda: fleet.time, seconds)
            fig[f"sitl_fleet_{n}_cpu_pct_of_core"] = cpu * 100.0
            fig[f"sitl_fleet_{n}_x_realtime"] = speed
            prev = n
            if speed >= 0.99 and cpu < 1.0:
                best = n
        if best is not None:
            per = fig[f"sitl_fleet_{best}_cpu_pct_of_core"] / best
            fig["sitl_fleet_realtime_max_n"] = float(best)
            fig["sitl_fleet_per_vehicle_cpu_pct_of_core"] = per
            fig["ratio_single_over_fleet_per_vehicle"] = \
                fig["sitl_single_250hz_cpu_pct_of_core"] / per
    finally:
        sink.close()
    return fig


def _fleet_ports(n, tries=20):
    """``n`` UDP sockets bound to consecutive loopback ports (BASE + k): where the vehicles of
    ``mavadrc sitl --count n --offboard-port BASE`` send."""
    import random
    import socket
    for _ in range(tries):
        base = random.randrange(20000, 60000 - n)
        socks = []
        try:
            for k in range(n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
                s.bind(("127.0.0.1", base + k))
                s.setblocking(False)
            return base, socks
        except OSError:
            for s in socks:
                s.close()
    raise RuntimeError(f"no {n} consecutive free UDP ports")


def count_as_shipped(n, seconds=5.0, rate_hz=100.0, start_timeout=180.0):
    """The command a user types, ``mavadrc sitl --count n --offboard-port BASE`` (the serving
    loop, physics and streams as shipped; only the ports chosen: BASE free, the ground-station
    link to a port nobody reads, the local ports any free ones), with a client in this process
    that asks each vehicle for LOCAL_POSITION_NED at ``rate_hz`` (SET_MESSAGE_INTERVAL), as a
    companion per vehicle would, and counts what arrives over ``seconds``.  Returns {"lpn_hz_min",
    "lpn_hz_median": per vehicle; "x_realtime": the slowest vehicle's clock (time_boot_ms)
    against the wall; "cpu_pct_of_core": the server's; "client_cpu_pct_of_core"}."""
    import os
    import selectors
    import statistics
    import struct
    import subprocess

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import common as mavlink

    from sim.lossy.frames import split_frames

    base, socks = _fleet_ports(n)
    sink = udp_sink()
    proc = subprocess.Popen([sys.executable, "-m", "sim", "--count", str(n), "--offboard-port",
                             str(base), "--gcs-port", str(sink.getsockname()[1]),
                             "--bind-offboard", "0", "--bind-gcs", "0"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    sel = selectors.DefaultSelector()
    for k, s in enumerate(socks):
        sel.register(s, selectors.EVENT_READ, k)
    enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_ONBOARD_COMPUTER)
    lpn = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
    counts, first, last = [0] * n, [None] * n, [None] * n
    peers = [None] * n

    def drain(measuring, until):
        while time.monotonic() < until:
            for key, _ in sel.select(0.05):
                k, s = key.data, key.fileobj
                while True:
                    try:
                        data, addr = s.recvfrom(65536)
                    except BlockingIOError:
                        break
                    if peers[k] is None:
                        peers[k] = addr
                        ask = mavlink.MAVLink_command_long_message(
                            k + 1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, lpn,
                            1e6 / rate_hz, 0, 0, 0, 0, 0)
                        s.sendto(ask.pack(enc), addr)
                    if not measuring:
                        continue
                    for frame in split_frames(data):
                        if frame.msgid == lpn:
                            # time_boot_ms opens the payload (after a 10-byte MAVLink 2 header,
                            # 6-byte MAVLink 1); MAVLink 2 cuts its trailing zero bytes
                            at, size = (6 if frame.v1 else 10), frame.raw[1]
                            head = bytes(frame.raw[at:at + min(4, size)]).ljust(4, b"\0")
                            boot = struct.unpack_from("<I", head)[0]
                            counts[k] += 1
                            if first[k] is None:
                                first[k] = (boot, time.monotonic())
                            last[k] = (boot, time.monotonic())
            if not measuring and all(p is not None for p in peers):
                return

    try:
        drain(False, time.monotonic() + start_timeout)
        if not all(p is not None for p in peers):
            raise RuntimeError(f"mavadrc sitl --count {n}: {peers.count(None)} vehicles silent "
                               f"after {start_timeout:g} s")
        drain(False, time.monotonic() + 2.0)  # the streams at the rate asked
        cpu0, own0, wall0 = _cpu_seconds(proc.pid), time.process_time(), time.monotonic()
        drain(True, wall0 + seconds)
        cpu1, own1, wall1 = _cpu_seconds(proc.pid), time.process_time(), time.monotonic()
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
        for s in socks:
            s.close()
        sink.close()
    wall = wall1 - wall0
    hz = [c / wall for c in counts]
    speed = [((b1 - b0) / 1e3) / (w1 - w0) for (b0, w0), (b1, w1) in zip(first, last)
             if w1 > w0] if all(f is not None for f in first) else [0.0]
    return {"lpn_hz_min": min(hz), "lpn_hz_median": statistics.median(hz),
            "x_realtime": min(speed), "cpu_pct_of_core": (cpu1 - cpu0) / wall * 100.0,
            "client_cpu_pct_of_core": (own1 - own0) / wall * 100.0}


def shipped_fleet_figures(counts=(1, 10, 20, 30, 40, 60, 100), seconds=5.0):
    """:func:`count_as_shipped` for each N of ``counts`` (stopping after the first that loses
    real time), and ``sitl_count_realtime_max_n``: the largest N whose every vehicle sent at
    least 95 of the 100 positions a second asked, its clock within 1 % of the wall clock, on
    less than one core."""
    fig, best = {}, None
    for n in counts:
        r = count_as_shipped(n, seconds)
        for key, value in r.items():
            fig[f"sitl_count_{n}_{key}"] = value
        holds = r["lpn_hz_min"] >= 95.0 and r["x_realtime"] >= 0.99 and \
            r["cpu_pct_of_core"] < 100.0
        if not holds:
            break
        best = n
    fig["sitl_count_realtime_max_n"] = float(best or 0)
    return fig


def _lockstep_hover(mavutil, port, seconds):
    """A 100 Hz LADRC position loop over pymavlink against a lockstep vehicle; x real time."""
    M = mavutil.mavlink
    c = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    c.wait_heartbeat(timeout=30)
    odo = M.MAVLINK_MSG_ID_ODOMETRY

    def command(cmd, *p):
        p = list(p) + [0.0] * (7 - len(p))
        c.mav.command_long_send(c.target_system, 1, cmd, 0, *p)
        c.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)

    for mid in (M.MAVLINK_MSG_ID_ATTITUDE, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
                M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED):
        command(M.MAV_CMD_SET_MESSAGE_INTERVAL, mid, -1)
    command(M.MAV_CMD_SET_MESSAGE_INTERVAL, odo, 10_000)
    ctrl = PositionController("ladrc", h=0.01, hover_thrust=0.5, wc=2.0, wo=10.0)
    ref = np.array([0.0, 0.0, -1.0])
    state = {"t": -1}

    def step():
        while True:
            m = c.recv_match(type="ODOMETRY", blocking=True, timeout=5)
            if m.time_usec > state["t"]:
                break
        state["t"] = m.time_usec
        q, thrust = ctrl.update([m.x, m.y, m.z], None, ref)
        c.mav.set_attitude_target_send(0, c.target_system, 1, 7, list(map(float, q)), 0, 0, 0,
                                     thrust)

    c.mav.set_attitude_target_send(0, c.target_system, 1, 7, [1.0, 0, 0, 0], 0, 0, 0, 0.0)
    step()
    command(M.MAV_CMD_DO_SET_MODE, 1, 6)
    command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    # waiting for the ACKs dropped the telemetry of the last step: one more setpoint moves the
    # lockstep clock on, and from here each step answers the sample its setpoint produced
    c.mav.set_attitude_target_send(0, c.target_system, 1, 7, [1.0, 0, 0, 0], 0, 0, 0, 0.0)
    for _ in range(100):  # the vehicle process loads its compiled kernels on first use
        step()
    n = int(seconds * 100)
    t0 = time.perf_counter()
    for _ in range(n):
        step()
    wall = time.perf_counter() - t0
    c.close()
    return n * 0.01 / wall


def fly_figures(realtime_seconds=10.0, lockstep_seconds=60.0):
    """`mavadrc fly` against the bundled vehicle: latency from telemetry receipt to setpoint
    sent in real time at 100 and 250 Hz (p99, and missed periods), and the wall time of a
    lockstep mission."""
    import io
    import tempfile
    from pathlib import Path

    from mavadrc.flight.fly import fly
    from mavadrc.mission.config import load_mission

    def hover_mission(folder, rate, seconds):
        path = Path(folder) / f"hover{rate}.yaml"
        path.write_text(
            f"name: bench hover\nvehicle: crazyflie\ncontroller: {{type: ladrc, rate_hz: {rate}}}\n"
            "trajectory:\n  - takeoff: {altitude: 1.0, speed: 1.0}\n"
            f"  - hover: {{duration: {seconds}}}\n  - land: {{speed: 1.0}}\n")
        return load_mission(path)

    fig = {}
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (100, 250):
            summary, _ = fly(hover_mission(tmp, rate, realtime_seconds), out=tmp,
                             progress=False, stream=io.StringIO())
            fig[f"fly_{rate}hz_latency_p99_us"] = summary["latency_p99_ms"] * 1e3
            fig[f"fly_{rate}hz_missed_periods_n"] = float(summary["missed_periods"])
        mission = hover_mission(tmp, 100, lockstep_seconds - 5.0)
        t0 = time.perf_counter()
        summary, _ = fly(mission, out=tmp, lockstep=True, progress=False,
                         stream=io.StringIO())
        fig["fly_lockstep_60s_mission_wall_s"] = time.perf_counter() - t0
        fig["fly_lockstep_mission_sim_s"] = summary["duration_s"]
        hover_mission(tmp, 100, 20.0)  # written as hover100.yaml
        fig.update(_lockstep_side_by_side(Path(tmp) / "hover100.yaml", tmp))
    return fig


def _lockstep_side_by_side(path, folder):
    """`mavadrc fly --lockstep` of the mission at ``path``, alone and then two at once (each
    its own companion and vehicle processes): the walls, and two at once over one.  On 2
    cores, for the bench's 29 s hover, two flights that wait for their peers asleep take
    1.3-1.7 times one; when both sides polled for each other's datagrams, 4.4."""
    import subprocess

    def run(n):
        t0 = time.perf_counter()
        procs = [subprocess.Popen([sys.executable, "-m", "mavadrc", "fly", str(path),
                                   "--lockstep", "--no-figures", "-q",
                                   "--out", f"{folder}/side{n}-{k}"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                 for k in range(n)]
        codes = [p.wait() for p in procs]
        if any(codes):
            raise RuntimeError(f"a lockstep flight of the bench failed (exit {codes})")
        return time.perf_counter() - t0

    one = run(1)
    two = run(2)
    return {"fly_lockstep_one_alone_wall_s": one, "fly_lockstep_two_at_once_wall_s": two,
            "ratio_fly_lockstep_two_at_once_over_one": two / one}


def compare_figures(seeds=10, mavlink=True):
    """`mavadrc compare` on configs/experiments/thesis.yaml: wall time and runs per second of
    the whole matrix for one seed and for ``seeds`` seeds (local worker processes, one per
    core; the runs actually flown, and the same seeds with every run flown,
    ``--rerun-identical``), and one run in process against the same run over MAVLink in
    lockstep."""
    import tempfile

    from mavadrc.study.compare import run_matrix, runs_flown
    from mavadrc.study.experiment import load_experiment, run_inprocess, run_mavlink

    exp = load_experiment("thesis")
    fig = {}
    run_matrix(exp, seeds=[0], progress=False, keep_logs_seed=None)  # compile / load caches
    for n in (1, seeds):
        records, _, wall = run_matrix(exp, seeds=list(range(n)), progress=False)
        flown = runs_flown(records)
        fig[f"compare_thesis_{n}seed_wall_s"] = wall
        fig[f"compare_thesis_{n}seed_runs_per_s"] = len(records) / wall
        fig[f"compare_thesis_{n}seed_runs_flown"] = flown
        fig[f"compare_thesis_{n}seed_runs_flown_per_s"] = flown / wall
    if seeds > 1:
        # the peer: every seed flown, including those of scenarios the seed does not change
        records, _, wall = run_matrix(exp, seeds=list(range(seeds)), progress=False,
                                      rerun_identical=True)
        fig[f"compare_thesis_{seeds}seed_rerun_identical_wall_s"] = wall
        fig[f"ratio_compare_{seeds}seed_rerun_identical_over_default"] = \
            wall / fig[f"compare_thesis_{seeds}seed_wall_s"]
    i = [sc.name for sc in exp.scenarios].index("spiral in wind, physical wind")
    j = [c.kind for c in exp.controllers].index("ladrc")
    t0 = time.perf_counter()
    rec, _ = run_inprocess(exp, i, j, 0)
    fig["compare_inprocess_run_s"] = time.perf_counter() - t0
    fig["compare_inprocess_sim_x_realtime"] = rec["duration_s"] / fig["compare_inprocess_run_s"]
    if mavlink:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            run_mavlink(exp, i, j, 0, tmp)
            fig["compare_mavlink_run_s"] = time.perf_counter() - t0
        fig["ratio_mavlink_over_inprocess_run"] = \
            fig["compare_mavlink_run_s"] / fig["compare_inprocess_run_s"]
    return fig


def bench_parts(sitl=True, compare=True, compare_seeds=10):
    """[(what it measures, the function that measures it)] of a bench run."""
    from sim.bench import physics_figures

    parts = [("the control laws' steps", control_figures),
             ("the vehicle's physics", physics_figures)]
    if sitl:
        parts += [("the bundled vehicle in real time and lockstep", sitl_figures),
                  ("a fleet of vehicles in one process", fleet_figures),
                  ("mavadrc sitl --count N as shipped, positions asked at 100 Hz",
                   shipped_fleet_figures),
                  ("flights over MAVLink", fly_figures)]
    if compare:
        parts.append((f"compare over {compare_seeds} seeds",
                      lambda: compare_figures(compare_seeds, mavlink=sitl)))
    return parts


def all_figures(sitl=True, compare=True, compare_seeds=10, progress=None):
    """Every figure, measured part by part; ``progress``: a :class:`Steps` told each part as
    it starts (the whole takes minutes)."""
    fig = {}
    for name, measure in bench_parts(sitl, compare, compare_seeds):
        if progress is not None:
            progress.describe(f"bench: {name}")
        fig.update(measure())
        if progress is not None:
            progress.step()
    return fig


def main(as_json=False, out=sys.stdout, sitl=True, compare=True, compare_seeds=10,
         progress=True):
    steps = Steps(len(bench_parts(sitl, compare, compare_seeds)), "part", out=sys.stderr,
                  enabled=progress)
    fig = all_figures(sitl, compare, compare_seeds, steps)
    steps.close()
    if as_json:
        out.write(json.dumps(fig) + "\n")
        return 0
    width = max(len(k) for k in fig)
    for k, v in fig.items():
        if v is None:
            peer = next(p for p in PEERS if p in k)
            out.write(f"{k:<{width}}  {peer} is not installed: {PEERS_INSTALL}\n")
        else:
            out.write(f"{k:<{width}}  {v:12.4g}\n")
    return 0
