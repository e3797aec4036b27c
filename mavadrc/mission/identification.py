"""The identification manoeuvre: acceleration doublets about a hover, then a drag leg; the
windows a fit reads, and the mission `mavadrc identify` flies."""


#: the doublets flown: amplitude (m/s^2 per axis), half period (s), repeats, rest after each axis
AMPLITUDE = (2.0, 2.0, 1.0)



HALF_PERIOD = 0.4



REPEATS = 2



REST_S = 1.0



#: the drag leg after the doublets (:class:`mavadrc.mission.trajectories.Doublets`): north and east
#: speed (m/s; diagonally 1.4 m/s, 2.8 m out and back), ramp and cruise (s), and how much of
#: the end of each cruise its commands and velocities are averaged over (s)
LEG_SPEED = 1.0



LEG_RAMP_S = 0.8



LEG_CRUISE_S = 2.0



LEG_WINDOW_S = 1.2



#: s the vehicle holds still at the identify segment's end while the fit is made (in real
#: time 1.6-2.6 s on PX4 SIH on 2 shared cores, in a thread beside the 100 Hz loop): the
#: mission's controller then takes over at rest, not in the run-up to the next segment, where
#: the safe observers' lagging disturbance estimate made its first commands jump
HANDOVER_S = 3.0



#: s before the identify segment's first sample (less MAX_DELAY_S and 0.1 s, from where the fit
#: reads its commands) at which a takeoff flown by the takeoff's PID (a mission's ``takeoff:
#: pid``) hands the vehicle to the safe LADRC: its transient from the PID's estimates over by
#: then
TAKEOFF_HANDOVER_S = 1.0



def doublets(position, yaw=0.0, amplitude=AMPLITUDE, leg_speed=LEG_SPEED):
    """The identification manoeuvre about ``position`` (NED): the doublets, then the drag leg
    at ``leg_speed`` (m/s north and east; 0: none)."""
    from mavadrc.mission.trajectories import Doublets
    return Doublets(position, amplitude=amplitude, half_period=HALF_PERIOD, repeats=REPEATS,
                    rest=REST_S, yaw=yaw, leg=(leg_speed, leg_speed) if leg_speed else None,
                    leg_ramp=LEG_RAMP_S, leg_cruise=LEG_CRUISE_S, leg_window=LEG_WINDOW_S,
                    hold=HANDOVER_S)



#: the hover the doublets are flown at, above the takeoff spot (m)
ALTITUDE = 1.0



def windows_in(phases, position=(0.0, 0.0, -ALTITUDE), leg_speed=LEG_SPEED):
    """The windows of the identify segment in mission time, from the mission's phases: the
    axes' doublets, then the drag leg's cruises (axis ``"leg"``) when it flies one."""
    t_id = dict((name, t0) for t0, name in phases)["identify"]
    d = doublets(position, leg_speed=leg_speed)
    return ([(ax, t_id + a, t_id + b) for ax, a, b in d.windows]
            + [("leg", t_id + a, t_id + b) for a, b in d.leg_windows])



def leg_speed_of(mission):
    """The drag leg's speed (m/s) of ``mission``'s identify segment (the default where it
    places none)."""
    return next((float(params.get("leg_speed", LEG_SPEED))
                 for kind, params, _ in mission.segments if kind == "identify"), LEG_SPEED)



