"""The bundled vehicle behind a MAVLink 2 endpoint on UDP, laid out like PX4 SITL.

Two links, as PX4 SITL has them: the offboard/API link sends to 127.0.0.1:14540+N (MAVSDK and
the `mavadrc fly` companion listen there) and the ground-station link sends to 127.0.0.1:14550
(QGroundControl, MAVProxy).  Each link binds its own local port (14580+N and 18570+N, PX4's
numbers) and also answers whoever writes to it.  Every datagram is parsed on its own; anything
malformed, badly signed, unknown or aimed at another system is dropped and counted, never acted
on.

Clocks: in real time the physics advances on the wall clock in ticks of ``tick`` seconds.  In
lockstep the vehicle advances by one ``lockstep_dt`` for each setpoint that arrives, so a
closed loop runs as fast as both sides allow and gives the same flight for the same seed; if
setpoints stop for ``lockstep_timeout`` (10 s) of wall time while armed, the offboard-loss failsafe
engages and the clock falls back to real time so the vehicle can carry it out.

The autopilot around the vehicle is as unkind as the real ones (:mod:`sim.autopilot`, with the
rules of :mod:`sim.personality`): HEARTBEAT at 1 Hz of vehicle time (PX4 sends no extra one when
the mode or the arming changes, ArduPilot one at a mode change), motors held at idle for a while
after arming, the autopilot's own land detector behind EXTENDED_SYS_STATE, disarm refusals and
automatic disarming, the offboard-loss failsafe without RC, and TIMESYNC on the vehicle's clock.

:class:`SitlServer` wires the parts together and runs them; each protocol concern has a module
of its own in :mod:`sim.mavlink` (link, receiver, commands, parameters, offboard setpoints,
streams, mission, FTP, TIMESYNC).
"""

import logging
import math
import select
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from . import personality as PP
from .link_model import LINK_FROM, PeriodLink
from .autopilot import Autopilot
from .mavlink import ftp, mission
from .mavlink.commands import Commands
from .mavlink.link import (GCS_RATES, LOOPBACK, LPN, ONBOARD_RATES, Link, Stats, bind_udp,
                           default_ports)
from .mavlink.offboard import Offboard
from .mavlink.parameters import Parameters
from .mavlink.realtime import RealtimeLink
from .mavlink.receiver import Receiver
from .mavlink.streams import Streams
from .mavlink.timesync import Timesync
from .sensors import CLOCK_RATES

log = logging.getLogger("mavadrc.sitl")

HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT


class SitlServer:
    """Runs a :class:`sim.vehicle.SimVehicle` behind MAVLink.

    ``SitlServer(vehicle, autopilot="px4", instance=0).run()`` blocks; ``start()`` runs it in a
    thread (tests) and ``stop()`` ends it.  A local port another socket holds raises
    :class:`sim.mavlink.link.PortInUse`.
    """

    def __init__(self, vehicle, autopilot="px4", instance=0, *, lockstep=False, lockstep_dt=0.01,
                 lockstep_timeout=10.0, tick=0.002, signing_key=None, home=(47.397742, 8.545594, 488.0),
                 host=LOOPBACK, offboard_port=None, gcs_port=None, bind_offboard=None,
                 bind_gcs=None, params=None, link=None, link_on=("offboard",),
                 link_bandwidth=None, link_seed=None, clock_rate=1.0):
        self.vehicle = vehicle
        # in real time the vehicle's clock (its time_boot_ms, TIMESYNC, streams) runs at this
        # share of the wall clock: below 1 as a simulator's that cannot keep up runs (PX4 SITL's
        # lockstep clock ran 1.35 % slow on 2 cores, 2026-12-03)
        lo, hi = CLOCK_RATES
        if not (math.isfinite(clock_rate) and lo <= clock_rate <= hi):
            raise ValueError(f"clock_rate must be {lo:g} to {hi:g} (got {clock_rate!r})")
        self.clock_rate = float(clock_rate)
        # the link model (sim.link_model.LinkModel): in real time on the datagrams of the links
        # in ``link_on`` (_impair), in lockstep on the control samples and setpoints
        # (_on_attitude_target); its draws from ``link_seed`` (default: the vehicle's seed)
        self.link_model = link if (link is not None and not link.perfect) else None
        self.link_seed = vehicle.seed if link_seed is None else link_seed
        self.plink = None
        self._lpn = {}  # period -> the LOCAL_POSITION_NED taken then, not yet delivered
        self._made = {}  # period -> the setpoint the companion made then, not yet applied
        self._applying = False
        self._fresh_link = False
        self.ap = PP.personality(autopilot)
        self.instance = int(instance)
        self.sysid = self.instance + 1
        self.lockstep = bool(lockstep)
        self.lockstep_dt = float(lockstep_dt)
        self.lockstep_timeout = float(lockstep_timeout)
        self.tick = float(tick)
        self.home = tuple(float(v) for v in home)
        self.stats = Stats()
        self._statustext_last = {}
        self._pending_steps = 0
        self._running = False
        self._thread = None
        self._last_hb_wall = 0.0
        self._last_step_wall = 0.0  # lockstep: wall time the clock last advanced
        self._stepped_wall = time.monotonic()  # wall time of the last step's sending
        self._last_hb_t = -10**9
        self.links = []
        ports = default_ports(self.instance, offboard_port, gcs_port, bind_offboard, bind_gcs)
        try:
            for name, rates in (("offboard", ONBOARD_RATES), ("gcs", GCS_RATES)):
                remote, local = ports[name]
                sock = bind_udp(host, local, name)
                rates = {mid: hz for mid, hz in rates.items() if self.ap.sends(mid)}
                self.links.append(Link(name, sock, (host, remote), self.sysid, rates, signing_key))
        except OSError:
            self._close()
            raise
        self.parameters = Parameters(self.ap, vehicle, self.sysid, params, self.statustext,
                                     self.statustext_limited)
        self.params = self.parameters.values
        self.autopilot = Autopilot(vehicle, self.ap, self.params, self.home, self.statustext,
                                   self._heartbeat_now, self._stream_stalled)
        self.streams = Streams(self.autopilot, self.sysid)
        self.offboard = Offboard(self.autopilot, self.stats, self.statustext_limited,
                                 self._setpoint_arrived)
        commands = Commands(self.autopilot, self.streams, self.stats, self.statustext,
                            stream_limits=not self.lockstep)
        self.receiver = Receiver(self.links, self.sysid, self.stats, {
            "COMMAND_LONG": commands.on_command,
            "COMMAND_INT": commands.on_command,
            "SET_MODE": commands.on_set_mode,
            "SET_ATTITUDE_TARGET": self._on_attitude_target,
            "SET_POSITION_TARGET_LOCAL_NED": self.offboard.on_position_target,
            "TIMESYNC": Timesync(self.clock_now).on_timesync,
            "PARAM_REQUEST_LIST": self.parameters.on_request_list,
            "PARAM_REQUEST_READ": self.parameters.on_request_read,
            "PARAM_SET": self.parameters.on_set,
            "MISSION_REQUEST_LIST": mission.on_request_list,
            "MISSION_CLEAR_ALL": mission.on_clear_all,
            "MISSION_COUNT": mission.on_count,
            "MISSION_REQUEST_INT": mission.on_request,
            "MISSION_REQUEST": mission.on_request,
            "FILE_TRANSFER_PROTOCOL": ftp.on_ftp,
        })
        self.realtime = self._impair(self.link_model, set(link_on), dict(link_bandwidth or {}),
                                     self.link_seed)

    def _impair(self, model, on, bandwidth, seed):
        """Bandwidth ({link name: bytes/s}) on the links named, and in real time the link model
        on the links in ``on``, applied on the wall clock (:mod:`sim.mavlink.realtime`); in
        lockstep the model is the lockstep path's to apply."""
        impaired = []
        for i, link in enumerate(self.links):
            link.clock = lambda: self.vehicle.time
            link.stats = self.stats
            if bandwidth.get(link.name):
                link.set_bandwidth(bandwidth[link.name], self.ap.tx_buffer_bytes,
                                   self.ap.bandwidth_throttle)
            modelled = model is not None and not model.perfect and link.name in on
            if not self.lockstep and (modelled or link.line is not None):
                impaired.append(RealtimeLink(link, model if modelled else None, seed, i,
                                             self.stats, lambda: self.vehicle.time,
                                             self.receiver.datagram))
        return impaired

    @property
    def local_ports(self):
        return {link.name: link.sock.getsockname()[1] for link in self.links}

    @property
    def mode(self):
        """The autopilot's mode (:class:`sim.personality.Mode`)."""
        return self.autopilot.mode

    @property
    def failsafe(self):
        return self.autopilot.failsafe

    @property
    def time(self):
        return self.vehicle.time

    # --- main loop -------------------------------------------------------------------------------

    def start(self):
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="mavadrc-sitl", daemon=True)
        self._thread.start()
        return self

    def stop(self):
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._close()

    def stop_soon(self):
        """Ask a running loop to end (from a signal handler or a timer)."""
        self._running = False

    def run(self):
        self._running = True
        try:
            self._loop()
        finally:
            self._close()

    def _close(self):
        for link in self.links:
            link.sock.close()

    def _loop(self):
        by_sock = {link.sock: link for link in self.links}
        socks = list(by_sock)
        next_tick = time.monotonic()
        while self._running:
            now = time.monotonic()
            # in lockstep the next setpoint is waited for asleep in select: polling for it kept
            # a core busy while the companion computed, and with two lockstep flights on two
            # cores each side's spin held the core its peer needed (2.5x the time)
            if self.lockstep and not self._lockstep_stalled():
                timeout = 0.1
            else:
                timeout = max(0.0, next_tick - now)
                for r in self.realtime:  # wake for the next datagram the link holds back
                    timeout = min(timeout, max(0.0, r.next_due() - now))
            readable, _, _ = select.select(socks, [], [], timeout)
            for sock in readable:
                self.receiver.drain(by_sock[sock])
            if self.realtime:
                now = time.monotonic()
                for r in self.realtime:
                    r.release(now)
            if self.lockstep and not self._lockstep_stalled():
                if self._pending_steps > 0:
                    self._last_step_wall = time.monotonic()
                while self._pending_steps > 0:
                    self._pending_steps -= 1
                    self.advance(self.lockstep_dt)
                self._wall_heartbeat()
                next_tick = time.monotonic()
                continue
            now = time.monotonic()
            if now >= next_tick:
                self.advance(self.tick)
                next_tick += self.tick / self.clock_rate
                if now - next_tick > 0.25:  # fell far behind (machine busy): resynchronise
                    self.stats.overruns += 1
                    next_tick = now

    def _setpoint_arrived(self):
        """In lockstep every well-formed setpoint advances the clock one period, whether or not
        the current mode acts on it: the companion's stream is the clock."""
        if self.lockstep and not self._applying:
            self._pending_steps += 1

    # --- the link model in lockstep ---------------------------------------------------------------
    #
    # From the arming on, the clock moves in control periods counted from it, and the samples
    # (LOCAL_POSITION_NED on the offboard link) and attitude setpoints pass through
    # sim.link_model.PeriodLink exactly as the in-process fast path passes them: at each period
    # the sample taken then is filed and the newest arrived one goes out (or none); the
    # companion's answer is filed under the period it answered in, and the newest arrived
    # setpoint is applied before the clock moves on.  A period in which no sample reaches the
    # companion ends at once (no answer will come).  Other messages pass untouched.

    def _link_active(self):
        """Whether samples and setpoints pass through the link model now: in lockstep, armed,
        from :data:`sim.link_model.LINK_FROM` s of vehicle time on."""
        if self.link_model is None or not self.lockstep:
            return False
        if not self.vehicle.armed:
            self.plink = None
            return False
        if self.plink is None and self.vehicle.time >= LINK_FROM - 1e-9:
            self.plink = PeriodLink(self.link_model, self.link_seed, self.lockstep_dt,
                                    self.vehicle.time)
            self._lpn.clear()
            self._made.clear()
            self._fresh_link = True
        return self.plink is not None

    def _on_attitude_target(self, link, msg):
        if self.plink is None or not self._link_active():
            return self.offboard.on_attitude_target(link, msg)
        k = self.plink.k
        self.plink.answered(k)
        self._made[k] = (link, msg)
        self._end_period()

    def _end_period(self):
        """Apply the newest setpoint that has arrived, and let the clock move one period."""
        k = self.plink.k
        a = self.plink.applied(k)
        if a is not None:
            made = self._made.pop(a)
            for old in [p for p in self._made if p < a]:
                del self._made[old]
            self._applying = True
            try:
                self.offboard.on_attitude_target(*made)
            finally:
                self._applying = False
        self._pending_steps += 1

    def _build_offboard(self, mid):
        """The offboard link's messages; its sample as the link model delivers it."""
        msg = self.streams.build(mid)
        if mid != LPN or self.plink is None or msg is None:
            return msg
        if self._fresh_link:  # the first period: its sample goes out on a perfect link
            self._fresh_link = False
            self.plink.sample(0)
            return msg
        k = self.plink.k + 1
        self._lpn[k] = msg
        s = self.plink.sample(k)
        if s is None:
            self._end_period()  # the companion gets nothing: nothing will answer
            return None
        out = self._lpn.pop(s)
        for old in [p for p in self._lpn if p < s]:
            del self._lpn[old]
        return out

    def _lockstep_stalled(self):
        """In lockstep, setpoints stopped for ``lockstep_timeout`` wall seconds while flying."""
        last = self.offboard.last_setpoint_wall
        if not (self.vehicle.armed and last > -math.inf):
            return False
        return time.monotonic() - last > self.lockstep_timeout

    def _stream_stalled(self):
        return self.lockstep and self._lockstep_stalled()

    def _wall_heartbeat(self):
        """Lockstep with the clock stopped (no setpoints yet, or a pause): a heartbeat each second
        of wall time, so that a client can connect before it streams.  While the clock runs,
        heartbeats keep to 1 Hz of vehicle time."""
        now = time.monotonic()
        if now - max(self._last_hb_wall, self._last_step_wall) >= 1.0:
            self._heartbeat_now()
            self._last_hb_wall = now

    # --- one step --------------------------------------------------------------------------------

    def advance(self, dt):
        """Advance the vehicle by dt and do everything the autopilot does per step."""
        self.autopilot.before_step(dt)
        self.vehicle.step(dt)
        self.autopilot.after_step(dt)
        self._send_due()

    def clock_now(self):
        """The vehicle's clock now (s): in real time its time at the last step plus the wall
        time since, at the clock's rate, up to one step (a sample is stamped at its step, so
        a TIMESYNC answered between steps with the step's time read the clock up to a step
        late, and every sample's age as much too short: negative ages); in lockstep the
        clock only moves with the steps."""
        if self.lockstep:
            return self.vehicle.time
        since = (time.monotonic() - self._stepped_wall) * self.clock_rate
        return self.vehicle.time + min(max(since, 0.0), self.tick)

    def _send_due(self):
        self._stepped_wall = time.monotonic()
        t = self.streams.time_us()
        if t - self._last_hb_t >= 1_000_000:
            self._heartbeat_now()
            self._last_hb_t = t
            self._last_hb_wall = time.monotonic()
        if self._link_active():
            self.links[0].send_due(t, self._build_offboard)
            for link in self.links[1:]:
                link.send_due(t, self.streams.build)
            return
        for link in self.links:
            link.send_due(t, self.streams.build)

    # --- sending on every link -------------------------------------------------------------------

    def _send_all(self, msg):
        for link in self.links:
            link.mav.send(msg)

    def _heartbeat_now(self):
        self._send_all(self.streams.build(HEARTBEAT))

    def statustext(self, severity, text):
        self._send_all(mavlink.MAVLink_statustext_message(severity, text[:50].encode()))
        log.info("STATUSTEXT %s", text)

    def statustext_limited(self, key, severity, text):
        """:meth:`statustext`, at most once a second (wall time) per ``key``."""
        now = time.monotonic()
        if now - self._statustext_last.get(key, -10.0) >= 1.0:
            self._statustext_last[key] = now
            self.statustext(severity, text)
