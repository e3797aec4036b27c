"""The flight's first phases: connect, setup, measure.

Connect: the autopilot's heartbeat names the system flown.  Setup: its identity, who owns it,
its parameters, the streams (each request confirmed).  Measure: idle setpoints stream while the
achieved sample rate is measured; then it is judged (:meth:`Preflight._judge_rate`).
"""

import time

from mavadrc.design.fitworker import FitWorker
from mavadrc.design.identify import load_fitting
from mavadrc.errors import FlightError, LinkError
from mavadrc.flight.console import ticking
from mavadrc.flight.rangefinder import RANGE_HZ
from mavadrc.flight.state import vehicle_mode
from mavadrc.flight.truth import TRUTH_HZ, TruthTrack
from mavadrc.mavlink.commands import TIMEOUT, result_name
from mavadrc.mavlink.dialect import M
from mavadrc.mavlink.sequence import sequence_for

#: vehicle time (s) over which the achieved sample rate is measured before arming
MEASURE_S = 1.0
#: below this share of the requested rate the flight says so and flies at the rate it gets
RATE_OK = 0.9
#: while waiting for the first heartbeat, a line every this many seconds
HEARTBEAT_SAY_S = 5
#: SET_MESSAGE_INTERVAL sent (0.5 s apart) before a stream is taken as unanswered; after one went
#: unanswered, the next are sent this many times (eight unanswered on PX4's list took 20 s)
STREAM_TRIES = 5
STREAM_TRIES_UNANSWERED = 2


class Preflight:
    """Connect, setup and the rate measurement."""

    def __init__(self, mission, link, record, clock, vehicle, notices, choice, ident, confirm,
                 setpoints, steering, takeoff, gate, tracks, *, lockstep, heartbeat_timeout,
                 deadline, watchdog):
        self.m = mission
        self.link = link
        self.rec = record
        self.clock = clock
        self.v = vehicle
        self.notices = notices
        self.choice = choice
        self.ident = ident
        self.confirm = confirm
        self.setpoints = setpoints
        self.steering = steering
        self.takeoff = takeoff
        self.gate = gate
        self.tracks = tracks
        self.lockstep = lockstep
        self.heartbeat_timeout = heartbeat_timeout
        self.deadline = deadline
        self.watchdog = watchdog  # raises if the vehicle we started died

    def connect(self):
        # the controller (and every kernel of the loop: compiled now, not mid-flight) is made
        # while the vehicle comes up; with the hover thrust still to be read, made again after
        say = self.notices.say
        from mavadrc.control.jit import needs_compiling
        from mavadrc.control.position import position_update

        compiling = needs_compiling(position_update)
        if compiling:
            say("compiling the controller's kernels (the first flight after an install or "
                "an update; numba caches them: later flights start at once)")
        c = self.choice
        with ticking(say, "still compiling the controller's kernels", enabled=compiling):
            c.make(c.hover if c.hover is not None else 0.5)
        if c.identifying():
            load_fitting()  # here too: where the fits' process cannot start, they run here
            if not self.lockstep and self.ident.fitter is None:
                self.ident.fitter = FitWorker()
                if self.ident.fitter.why_not is not None:
                    say("the input model will be fitted in a thread beside the loop (its "
                        f"process did not start: {self.ident.fitter.why_not})")
        timeout = self.heartbeat_timeout
        if self.deadline is not None:
            timeout = min(timeout, max(0.0, self.deadline - time.monotonic()))
        waited = [0]
        # a vehicle of ours answers within a second; another is waited for aloud, from the start
        first = 0 if self.watchdog is None else 3

        def idle():
            if self.watchdog is not None:
                self.watchdog()
            s = waited[0]
            waited[0] += 1
            if s == first:
                say(f"waiting for an autopilot's heartbeat on {self.link.url} (up to "
                    f"{timeout:.0f} s; Ctrl-C to stop)")
            elif s > first and s % HEARTBEAT_SAY_S == 0:
                say(f"still waiting for a heartbeat on {self.link.url} ({s} s)")

        hb = self.link.wait_heartbeat(timeout, idle=idle)
        self.v.seq = sequence_for(self.link.autopilot, self.choice.kind)
        others = sorted(self.link.systems_heard - {self.link.target_system})
        say(f"connected to system {self.link.target_system} ({self.link.autopilot}, "
            f"{vehicle_mode(self.link, hb.custom_mode)}) on {self.link.url}"
            + (f"; also heard system {', '.join(map(str, others))} (--sysid picks one)"
               if others else ""))

    def setup(self):
        link, v, c, say = self.link, self.v, self.choice, self.notices.say
        seq = v.seq
        self.clock.phase = "setup"
        self._identify_vehicle()
        self._owner_check()
        if c.hover is None:
            name = seq.hover_param
            c.hover = float(link.param_read(name))
            v.sources["hover_thrust"] = f"the vehicle's {name}"
            c.make(c.hover)
        say(f"hover thrust {c.hover:.3f} from {v.sources['hover_thrust']}")
        if seq.motor_delay_param is None:
            v.motor_delay = seq.motor_delay_default
            v.sources["motor_delay"] = f"{seq.name}'s arming delay"
        else:
            v.motor_delay = max(0.0, float(self.read_param(seq.motor_delay_param,
                                                           seq.motor_delay_default)))
            v.sources["motor_delay"] = seq.motor_delay_param
        self._request_streams()
        # before the setpoint stream (and a lockstep clock) starts
        seq.preflight(link, self.m.safety, say, self.read_param, v.sources)
        for key in ("angle_boost",):
            if key in v.sources:
                say(v.sources[key])
        self.gate.restart(c.h)
        self.clock.enter("measure", None)

    def read_param(self, name, default):
        """A parameter of the vehicle, or ``default`` (said so) when it does not answer."""
        try:
            value = float(self.link.param_read(name))
        except LinkError:
            self.notices.say(f"the vehicle did not answer a read of {name}: using {default:g}")
            return default
        return value

    def _identify_vehicle(self):
        """AUTOPILOT_VERSION: firmware version, and whether this is the bundled vehicle."""
        link, v = self.link, self.v
        result = link.command_wait(M.MAV_CMD_REQUEST_MESSAGE,
                                   M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, tries=2)
        end = time.monotonic() + (0.5 if result == M.MAV_RESULT_ACCEPTED else 0.0)
        while "AUTOPILOT_VERSION" not in link.messages and time.monotonic() < end:
            link.recv(0.02)
        av = link.messages.get("AUTOPILOT_VERSION")
        v.identity = {"autopilot": link.autopilot, "system_id": link.target_system}
        if av is not None:
            ver = av.flight_sw_version
            kinds = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}
            v.identity["firmware_version"] = (
                f"{ver >> 24 & 0xFF}.{ver >> 16 & 0xFF}.{ver >> 8 & 0xFF} "
                f"{kinds.get(ver & 0xFF, ver & 0xFF)}")
            custom = bytes(av.flight_custom_version).rstrip(b"\0")
            if v.bundled is None:
                v.bundled = custom == b"mavadrc"
        if v.bundled is None:
            v.bundled = False
        v.identity["bundled_vehicle"] = v.bundled

    def _owner_check(self):
        """Armed, in the air or already in the mode that takes setpoints: another controller
        owns the vehicle.  Refused (nothing sent that changes mode, arming or thrust) unless
        takeover."""
        link, v, say = self.link, self.v, self.notices.say
        hb = link.heartbeat
        link.command_wait(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, tries=2)
        end = time.monotonic() + 0.3
        while "EXTENDED_SYS_STATE" not in link.messages and time.monotonic() < end:
            link.recv(0.02)
        ess = link.messages.get("EXTENDED_SYS_STATE")
        in_air = ess is not None and ess.landed_state not in (M.MAV_LANDED_STATE_ON_GROUND,
                                                              M.MAV_LANDED_STATE_UNDEFINED)
        owned = []
        if link.armed:
            owned.append("armed")
        if in_air:
            owned.append("in the air")
        if v.seq.in_control(hb):
            owned.append(f"in {vehicle_mode(link, hb.custom_mode)}")
        v.takeover_in_air = False
        if not owned:
            if v.takeover:
                say("--takeover: the vehicle is on the ground and disarmed, flying as usual")
                v.takeover = False
            return
        what = ", ".join(owned)
        if not v.takeover:
            hint = ""
            if not link.armed and not in_air:
                hint = (f" (a disarmed vehicle on the ground left in {v.seq.control_mode}: "
                        "PX4 returns to it after a failsafe landing; switch it to another mode)")
            raise FlightError(
                f"system {link.target_system} is {what}: another controller owns it, so mavadrc "
                "sent nothing that changes its mode, arming or thrust; land it first, or give "
                f"--takeover to fly it from where it is{hint}")
        v.takeover_in_air = link.armed and (in_air or ess is None)
        say(f"--takeover: system {link.target_system} is {what}; flying it from where it is")
        if not link.armed:
            v.takeover = False  # disarmed on the ground: an ordinary flight from here

    def _request_streams(self):
        v = self.v
        rate = self.m.controller.rate_hz
        wanted = [(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, rate), (M.MAVLINK_MSG_ID_ATTITUDE, rate),
                  (M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 10.0)]
        if v.bundled and v.seq.debug_vect:
            wanted.append((M.MAVLINK_MSG_ID_DEBUG_VECT, rate))  # the simulator's true disturbance
        for mid in v.seq.unused_streams:
            wanted.append((mid, 0))  # not used: spare the link
        # a downward range finder, if the vehicle has one (mavadrc.flight.rangefinder): PX4
        # streams it on its onboard link by itself, ArduPilot when asked; a vehicle without one
        # refuses it or sends nothing, and nothing changes
        optional = {"DISTANCE_SENSOR"}
        wanted.append((M.MAVLINK_MSG_ID_DISTANCE_SENSOR, min(rate, RANGE_HZ)))
        truth = v.seq.truth_message
        if truth is not None:
            # a simulator's true state, to measure the flight against (mavadrc.flight.truth); a
            # real vehicle refuses it or sends none, and nothing changes
            wanted.append((getattr(M, "MAVLINK_MSG_ID_" + truth), min(rate, TRUTH_HZ)))
            optional.add(truth)
            self.tracks.truth = TruthTrack(truth, table=self.rec.truth_table)
        v.streams = {}
        tries = STREAM_TRIES
        for mid, hz in wanted:
            result = self.link.set_rate(mid, hz, tries=tries)
            # unanswered through every try: a vehicle (or a router) that ignores these is asked
            # the rest fewer times; any answer restores the full count
            tries = STREAM_TRIES_UNANSWERED if result == TIMEOUT else STREAM_TRIES
            name = M.mavlink_map[mid].msgname if mid in M.mavlink_map else str(mid)
            v.streams[name] = result_name(result)
            if result != M.MAV_RESULT_ACCEPTED and hz > 0 and name not in optional:
                self.notices.say(f"the vehicle answered {result_name(result)} to {name} at "
                                 f"{hz:g} Hz")

    def measure_phase(self, s):
        if self.clock.t0 is None:
            self.clock.t0 = s.t
            self.takeoff.start_reference(s)
        if self.v.takeover_in_air:
            self.steering.step(s, None, hold=True)
        else:
            self.setpoints.idle(s.t, self.v.yaw)
        if self.gate.span < MEASURE_S or self.gate.received < 5:
            return
        self._judge_rate()
        why = self.link.sources_text()
        if why is not None:
            raise FlightError(f"{why}: not flying")
        self.confirm.cmd = self.v.seq.request_control(self.link)
        self.confirm.tries = 1
        self.clock.enter("mode", s)

    def _judge_rate(self):
        """The rate the samples come at, against the one asked for.  Samples lost on the link
        (gaps in the MAVLink sequence) or come out of order (behind a newer one, dropped) leave
        the stream's rate as it is: the steps are timed by the vehicle across the gaps.  A
        vehicle that sends slower than asked is flown at the rate it sends, and said so.  Below
        ``safety.min_rate_hz`` the flight is refused."""
        c, sources, say = self.choice, self.v.sources, self.notices.say
        asked = self.m.controller.rate_hz
        got = self.gate.achieved_rate()
        lost = self.link.frame_loss()
        arrived = self.gate.arrival_rate()
        stream = arrived / (1.0 - lost) if lost < 0.9 else arrived
        # what was measured over the window, no more: the frames lost in it (the first second
        # of a link can lose more than the rest: 14 % for 5.7 % behind the faulty proxy) make
        # ``stream`` an estimate, said only where the flight's rate is set from it (below)
        seen = f"{got:.1f} Hz reach us in order"
        if arrived > got:
            seen += (f" ({arrived:.1f} Hz in all, {100 * (1.0 - got / arrived):.0f} % of them "
                     "out of order: behind a newer one, dropped)")
        seen += f"; {100 * lost:.0f} % of the vehicle's frames were lost on the link meanwhile"
        if got < self.m.safety.min_rate_hz:
            raise FlightError(f"{seen}, where {asked:g} Hz was asked: below safety.min_rate_hz "
                              f"{self.m.safety.min_rate_hz:g}, not flying")
        if stream >= RATE_OK * asked:
            sources["rate"] = f"{asked:g} Hz asked, {got:.1f} Hz measured"
            if got < RATE_OK * asked:
                sources["rate"] = f"{asked:g} Hz asked; {seen}"
                say(f"warning: {seen}: flying at {asked:g} Hz, each step timed by the vehicle")
                self.notices.warnings.append(sources["rate"])
            return
        c.set_rate(round(stream, 1))
        c.make(c.hover)
        self.gate.restart(c.h)
        sources["rate"] = (f"{asked:g} Hz asked; {seen}: the vehicle sends about "
                           f"{stream:.1f} Hz, flying at {c.rate:g} Hz, each step timed "
                           "by the vehicle")
        say(f"warning: the vehicle sends about {stream:.1f} Hz, not the {asked:g} Hz "
            f"asked ({seen}): flying the controller at {c.rate:g} Hz")
        self.notices.warnings.append(sources["rate"])
