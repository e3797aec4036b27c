"""The flight's first phases: connect, setup, measure (:class:`Preflight`, a part of
:class:`~mavadrc.flight.flight.Flight`).

Connect: the autopilot's heartbeat names the system flown.  Setup: its identity, who owns it,
its parameters, the streams (each request confirmed).  Measure: idle setpoints stream while the
achieved sample rate is measured; then it is judged (:meth:`Preflight._judge_rate`).
"""

import time


from mavadrc.design.fitworker import FitWorker
from mavadrc.design.identify import load_fitting
from mavadrc.errors import FlightError
from mavadrc.mavlink.commands import TIMEOUT, result_name
from mavadrc.mavlink.dialect import M
from mavadrc.mavlink.errors import LinkError
from mavadrc.flight.rangefinder import RANGE_HZ
from mavadrc.mavlink.sequence import sequence_for
from mavadrc.flight.truth import TRUTH_HZ, TruthTrack

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
    """Connect, setup and the rate measurement (methods of :class:`~mavadrc.flight.flight.Flight`)."""

    def _connect(self):
        # the controller (and every kernel of the loop: compiled now, not mid-flight) is made
        # while the vehicle comes up; with the hover thrust still to be read, made again after
        from mavadrc.control._jit import needs_compiling
        from mavadrc.control.position import position_update

        if needs_compiling(position_update):
            self.say("compiling the controller's kernels (the first flight after an install or "
                     "an update; numba caches them: later flights start at once)")
        self.ctrl = self._make_controller(self.hover if self.hover is not None else 0.5)
        if self._identifying():
            load_fitting()  # here too: where the fits' process cannot start, they run here
            if not self.lockstep and self._fitter is None:
                self._fitter = FitWorker()
                if self._fitter.why_not is not None:
                    self.say("the input model will be fitted in a thread beside the loop (its "
                             f"process did not start: {self._fitter.why_not})")
        timeout = self.heartbeat_timeout
        if self._deadline is not None:
            timeout = min(timeout, max(0.0, self._deadline - time.monotonic()))
        waited = [0]
        # a vehicle of ours answers within a second; another is waited for aloud, from the start
        first = 0 if self.watchdog is None else 3

        def idle():
            if self.watchdog is not None:
                self.watchdog()
            s = waited[0]
            waited[0] += 1
            if s == first:
                self.say(f"waiting for an autopilot's heartbeat on {self.link.url} (up to "
                         f"{timeout:.0f} s; Ctrl-C to stop)")
            elif s > first and s % HEARTBEAT_SAY_S == 0:
                self.say(f"still waiting for a heartbeat on {self.link.url} ({s} s)")

        hb = self.link.wait_heartbeat(timeout, idle=idle)
        self.seq = sequence_for(self.link.autopilot)
        others = sorted(self.link.systems_heard - {self.link.target_system})
        self.say(f"connected to system {self.link.target_system} ({self.link.autopilot}, "
                 f"{self.mode_name(hb.custom_mode)}) on {self.link.url}"
                 + (f"; also heard system {', '.join(map(str, others))} (--sysid picks one)"
                    if others else ""))

    def _setup(self):
        link = self.link
        self.phase = "setup"
        self._identify()
        self._owner_check()
        if self.hover is None:
            name = self.seq.hover_param
            self.hover = float(link.param_read(name))
            self.sources["hover_thrust"] = f"the vehicle's {name}"
            self.ctrl = self._make_controller(self.hover)
        self.say(f"hover thrust {self.hover:.3f} from {self.sources['hover_thrust']}")
        if self.seq.motor_delay_param is None:
            self.motor_delay = self.seq.motor_delay_default
            self.sources["motor_delay"] = f"{self.seq.name}'s arming delay"
        else:
            self.motor_delay = max(0.0, float(self.read_param(self.seq.motor_delay_param,
                                                              self.seq.motor_delay_default)))
            self.sources["motor_delay"] = self.seq.motor_delay_param
        self._request_streams()
        self.seq.preflight(self)  # before the setpoint stream (and a lockstep clock) starts
        for key in ("angle_boost",):
            if key in self.sources:
                self.say(self.sources[key])
        self.gate.restart(self.h)
        self._enter("measure", None)

    def read_param(self, name, default):
        """A parameter of the vehicle, or ``default`` (said so) when it does not answer."""
        try:
            value = float(self.link.param_read(name))
        except LinkError:
            self.say(f"the vehicle did not answer a read of {name}: using {default:g}")
            return default
        return value

    def _identify(self):
        """AUTOPILOT_VERSION: firmware version, and whether this is the bundled vehicle."""
        result = self.link.command_wait(M.MAV_CMD_REQUEST_MESSAGE,
                                        M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, tries=2)
        end = time.monotonic() + (0.5 if result == M.MAV_RESULT_ACCEPTED else 0.0)
        while "AUTOPILOT_VERSION" not in self.link.messages and time.monotonic() < end:
            self.link.recv(0.02)
        av = self.link.messages.get("AUTOPILOT_VERSION")
        self.identity = {"autopilot": self.link.autopilot, "system_id": self.link.target_system}
        if av is not None:
            v = av.flight_sw_version
            kinds = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}
            self.identity["firmware_version"] = (
                f"{v >> 24 & 0xFF}.{v >> 16 & 0xFF}.{v >> 8 & 0xFF} {kinds.get(v & 0xFF, v & 0xFF)}")
            custom = bytes(av.flight_custom_version).rstrip(b"\0")
            if self.bundled is None:
                self.bundled = custom == b"mavadrc"
        if self.bundled is None:
            self.bundled = False
        self.identity["bundled_vehicle"] = self.bundled

    def _owner_check(self):
        """Armed, in the air or already in the mode that takes setpoints: another controller
        owns the vehicle.  Refused (nothing sent that changes mode, arming or thrust) unless
        takeover."""
        link = self.link
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
        if self.seq.in_control(hb):
            owned.append(f"in {self.mode_name(hb.custom_mode)}")
        self.takeover_in_air = False
        if not owned:
            if self.takeover:
                self.say("--takeover: the vehicle is on the ground and disarmed, flying as usual")
                self.takeover = False
            return
        what = ", ".join(owned)
        if not self.takeover:
            hint = ""
            if not link.armed and not in_air:
                hint = (f" (a disarmed vehicle on the ground left in {self.seq.control_mode}: "
                        "PX4 returns to it after a failsafe landing; switch it to another mode)")
            raise FlightError(
                f"system {link.target_system} is {what}: another controller owns it, so mavadrc "
                "sent nothing that changes its mode, arming or thrust; land it first, or give "
                f"--takeover to fly it from where it is{hint}")
        self.takeover_in_air = link.armed and (in_air or ess is None)
        self.say(f"--takeover: system {link.target_system} is {what}; flying it from where it is")
        if not link.armed:
            self.takeover = False  # disarmed on the ground: an ordinary flight from here

    def _request_streams(self):
        rate = self.m.controller.rate_hz
        wanted = [(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, rate), (M.MAVLINK_MSG_ID_ATTITUDE, rate),
                  (M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 10.0)]
        if self.bundled and self.seq.debug_vect:
            wanted.append((M.MAVLINK_MSG_ID_DEBUG_VECT, rate))  # the simulator's true disturbance
        for mid in self.seq.unused_streams:
            wanted.append((mid, 0))  # not used: spare the link
        # a downward range finder, if the vehicle has one (mavadrc.flight.rangefinder): PX4 streams it
        # on its onboard link by itself, ArduPilot when asked; a vehicle without one refuses
        # it or sends nothing, and nothing changes
        optional = {"DISTANCE_SENSOR"}
        wanted.append((M.MAVLINK_MSG_ID_DISTANCE_SENSOR, min(rate, RANGE_HZ)))
        truth = self.seq.truth_message
        if truth is not None:
            # a simulator's true state, to measure the flight against (mavadrc.flight.truth); a real
            # vehicle refuses it or sends none, and nothing changes
            wanted.append((getattr(M, "MAVLINK_MSG_ID_" + truth), min(rate, TRUTH_HZ)))
            optional.add(truth)
            self.truth = TruthTrack(truth, table=self.rec.truth_table)
        self.streams = {}
        tries = STREAM_TRIES
        for mid, hz in wanted:
            result = self.link.set_rate(mid, hz, tries=tries)
            # unanswered through every try: a vehicle (or a router) that ignores these is asked
            # the rest fewer times; any answer restores the full count
            tries = STREAM_TRIES_UNANSWERED if result == TIMEOUT else STREAM_TRIES
            name = M.mavlink_map[mid].msgname if mid in M.mavlink_map else str(mid)
            self.streams[name] = result_name(result)
            if result != M.MAV_RESULT_ACCEPTED and hz > 0 and name not in optional:
                self.say(f"the vehicle answered {result_name(result)} to {name} at {hz:g} Hz")

    def _ph_measure(self, s):
        if self._phase_t0 is None:
            self._phase_t0 = s.t
            self._start_reference(s)
        if self.takeover_in_air:
            self._control_step(s, None, hold=True)
        else:
            self._idle(s)
        if self.gate.span < MEASURE_S or self.gate.received < 5:
            return
        self._judge_rate()
        why = self.link.sources_text()
        if why is not None:
            raise FlightError(f"{why}: not flying")
        self._cmd = self.seq.request_control(self.link)
        self._cmd_tries = 1
        self._enter("mode", s)

    def _judge_rate(self):
        """The rate the samples come at, against the one asked for.  Samples lost on the link
        (gaps in the MAVLink sequence) or come out of order (behind a newer one, dropped) leave
        the stream's rate as it is: the steps are timed by the vehicle across the gaps.  A
        vehicle that sends slower than asked is flown at the rate it sends, and said so.  Below
        ``safety.min_rate_hz`` the flight is refused."""
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
            self.sources["rate"] = f"{asked:g} Hz asked, {got:.1f} Hz measured"
            if got < RATE_OK * asked:
                self.sources["rate"] = f"{asked:g} Hz asked; {seen}"
                self.say(f"warning: {seen}: flying at {asked:g} Hz, each step timed by the "
                         "vehicle")
                self.warnings.append(self.sources["rate"])
            return
        self.rate = round(stream, 1)
        self.h = 1.0 / self.rate
        self.ctrl = self._make_controller(self.hover)
        self.gate.restart(self.h)
        self.sources["rate"] = (f"{asked:g} Hz asked; {seen}: the vehicle sends about "
                                f"{stream:.1f} Hz, flying at {self.rate:g} Hz, each step timed "
                                "by the vehicle")
        self.say(f"warning: the vehicle sends about {stream:.1f} Hz, not the {asked:g} Hz "
                 f"asked ({seen}): flying the controller at {self.rate:g} Hz")
        self.warnings.append(self.sources["rate"])
