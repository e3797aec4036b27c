"""Mode and arming: each command confirmed by its answer and by a heartbeat newer than it (a
lost answer is settled by the heartbeat); a refusal ends the flight with the vehicle's reason."""

from mavadrc.errors import FlightError
from mavadrc.flight.state import vehicle_mode
from mavadrc.mavlink.commands import TIMEOUT, result_name
from mavadrc.mavlink.dialect import M


class Arming:
    """The mode that takes setpoints, then arming; taken over in the air, the mission starts
    once the mode is confirmed."""

    def __init__(self, link, clock, vehicle, notices, confirm, setpoints, steering, takeoff):
        self.link = link
        self.clock = clock
        self.v = vehicle
        self.notices = notices
        self.confirm = confirm
        self.setpoints = setpoints
        self.steering = steering
        self.takeoff = takeoff
        self._retry_t = None  # vehicle time to ask for the mode again after a refusal

    def mode_phase(self, s):
        v, confirm, seq = self.v, self.confirm, self.v.seq
        if v.takeover_in_air:
            self.steering.step(s, None, hold=True)
        else:
            self.setpoints.idle(s.t, v.yaw)
        c = confirm.cmd
        if c is not None and c.done:
            confirm.unheard = c.result == TIMEOUT
            if confirm.refused_answer(c, "the mode change", "its mode"):
                if c.result == M.MAV_RESULT_TEMPORARILY_REJECTED and confirm.tries < 5:
                    confirm.tries += 1  # PX4: the setpoint stream is not seen yet
                    self._retry_t = s.t + 0.3
                else:
                    raise FlightError(f"the vehicle refused {seq.control_mode}: "
                                      f"{result_name(c.result)}{self.notices.because()}")
        if self._retry_t is not None and s.t >= self._retry_t - 1e-9:
            self._retry_t = None
            confirm.cmd = seq.request_control(self.link)
            return
        hb = confirm.fresh()
        if hb is not None and seq.in_control(hb):
            v.in_control_seen = True
            self.notices.say(f"in {vehicle_mode(self.link, hb.custom_mode)}")
            confirm.since = None
            if v.takeover_in_air:
                return self.takeoff.start_mission(s)
            confirm.cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            confirm.unheard, confirm.asked_again = False, 0
            self.clock.enter("arming", s)
        elif confirm.ask_again(hb, f"not in {seq.control_mode}"):
            confirm.cmd = seq.request_control(self.link)

    def arming_phase(self, s):
        v, confirm, say = self.v, self.confirm, self.notices.say
        self.setpoints.idle(s.t, v.yaw)
        c = confirm.cmd
        if c is not None and c.done:
            confirm.unheard = c.result == TIMEOUT
            if confirm.refused_answer(c, "the arm command", "whether it armed"):
                raise FlightError(f"the vehicle refused to arm: {result_name(c.result)}"
                                  f"{self.notices.because()}")
        hb = confirm.fresh()
        if hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and \
                confirm.ask_again(hb, "not armed"):
            confirm.cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        if hb is not None and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            confirm.since = None
            if v.takeover:  # armed on the ground already: the motors are up
                say("armed: flying from the ground, no spool-up")
                return self.takeoff.start_mission(s)
            say(f"armed; motors start in {v.motor_delay:g} s "
                f"({v.sources.get('motor_delay', 'default')}), then the spool-up")
            self.clock.enter("spoolup", s)  # from the next sample: one setpoint per sample
