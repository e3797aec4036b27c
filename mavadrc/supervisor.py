"""The flight's safety checks, apart from the phases that fly: what is wrong, not what to do.

Each check looks at a sample or at the clock and names what it found; the flight turns that
into an action (level hover, hold, the autopilot's land mode).
"""

import math


class Supervisor:
    def __init__(self, safety, telemetry_timeout):
        self.sf = safety
        self.telemetry_timeout = telemetry_timeout

    def breach(self, s, origin):
        """The geofence, altitude or speed limit ``s`` breaks (relative to ``origin``), or
        None."""
        sf = self.sf
        north, east, down = (s.pos - origin).tolist()
        alt = -down
        vn, ve, vd = s.vel.tolist()
        speed = math.sqrt(vn * vn + ve * ve + vd * vd)
        if not sf.geofence_north[0] <= north <= sf.geofence_north[1] or \
                not sf.geofence_east[0] <= east <= sf.geofence_east[1]:
            return f"geofence breach at north {north:.1f} m, east {east:.1f} m"
        if alt > sf.altitude_max or alt < sf.altitude_min:
            return f"altitude limit breach at {alt:.1f} m"
        if speed > sf.max_speed:
            return f"speed limit breach at {speed:.1f} m/s"
        return None

    def stale_for(self, now, last_sample_wall, last_send_wall):
        """Seconds telemetry has been stale beyond the timeout (<= 0: fresh).  Counted from the
        last sample, or from our answer to it if that took long: a lockstep vehicle cannot
        move on before our answer."""
        return now - max(last_sample_wall, last_send_wall) - self.telemetry_timeout
