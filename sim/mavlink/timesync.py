"""TIMESYNC, answered on the vehicle's own clock, the clock of every time_boot_ms it sends."""

from pymavlink.dialects.v20 import ardupilotmega as mavlink


class Timesync:
    """``clock()``: the vehicle's clock now, in seconds since boot."""

    def __init__(self, clock):
        self.clock = clock

    def on_timesync(self, link, msg):
        """Answer a request (tc1 == 0) with tc1 = the vehicle's clock in ns since boot (PX4
        mavlink_timesync.cpp: hrt_absolute_time(); ArduPilot GCS_MAVLINK::handle_timesync:
        micros64 at reception)."""
        if msg.tc1 == 0:
            tc1 = max(1, int(round(self.clock() * 1e9)))  # 0 would read as a request
            link.mav.send(mavlink.MAVLink_timesync_message(tc1, msg.ts1))
