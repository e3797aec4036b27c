"""Autopilot personalities of the bundled vehicle: how PX4 and ArduCopter look on the wire.

A personality owns the heartbeat identity, the custom-mode encoding, the mapping from a mode
command to one of the vehicle's behaviours, the parameter set and the offboard rules.  The
vehicle's behaviours (the ``Behaviour`` names) are shared: hold, takeoff, land, rtl, and the two
that accept external setpoints, offboard (PX4) and guided (ArduPilot).
"""

from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

# behaviours of the simulated autopilot
HOLD = "hold"
TAKEOFF = "takeoff"
LAND = "land"
RTL = "rtl"
OFFBOARD = "offboard"  # PX4 OFFBOARD and ArduPilot GUIDED / GUIDED_NOGPS: external setpoints

INT = mavlink.MAV_PARAM_TYPE_INT32
REAL = mavlink.MAV_PARAM_TYPE_REAL32


@dataclass(frozen=True)
class Mode:
    name: str
    custom_mode: int
    behaviour: str
    armable: bool = True


def px4_custom_mode(main, sub=0):
    return (main << 16) | (sub << 24)


PX4_MAIN = {"MANUAL": 1, "ALTCTL": 2, "POSCTL": 3, "AUTO": 4, "ACRO": 5, "OFFBOARD": 6,
            "STABILIZED": 7}
PX4_AUTO_SUB = {"READY": 1, "TAKEOFF": 2, "LOITER": 3, "MISSION": 4, "RTL": 5, "LAND": 6}


@dataclass
class Personality:
    name: str
    autopilot: int
    modes: dict
    initial_mode: str
    params: list  # (name, default, MAV_PARAM_TYPE)
    capabilities: int
    bytewise_params: bool
    flight_sw_version: int
    mode_aliases: dict = field(default_factory=dict)

    def mode(self, name):
        return self.modes[name]

    def mode_from_custom(self, custom_mode):
        for m in self.modes.values():
            if m.custom_mode == custom_mode:
                return m
        return None


_CAPS = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
         | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
         | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
         | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
         | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
         | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT)

_WIND_PARAMS = [
    ("SIM_WIND_SPD", 0.0, REAL),  # mean wind speed (m/s) added by the ground station
    ("SIM_WIND_DIR", 0.0, REAL),  # direction it blows from (deg)
    ("SIM_WIND_TURB", 0.0, REAL),  # Dryden turbulence: wind speed at 6 m (m/s) setting its intensity
    ("SIM_WIND_DIR_Z", 0.0, REAL),  # vertical wind (m/s, positive up)
]


def px4():
    P = px4_custom_mode
    modes = {
        "MANUAL": Mode("MANUAL", P(1), HOLD),
        "ALTCTL": Mode("ALTCTL", P(2), HOLD),
        "POSCTL": Mode("POSCTL", P(3), HOLD),
        "OFFBOARD": Mode("OFFBOARD", P(6), OFFBOARD),
        "STABILIZED": Mode("STABILIZED", P(7), HOLD),
        "AUTO.READY": Mode("AUTO.READY", P(4, 1), HOLD),
        "AUTO.TAKEOFF": Mode("AUTO.TAKEOFF", P(4, 2), TAKEOFF),
        "AUTO.LOITER": Mode("AUTO.LOITER", P(4, 3), HOLD),
        "AUTO.RTL": Mode("AUTO.RTL", P(4, 5), RTL, armable=False),
        "AUTO.LAND": Mode("AUTO.LAND", P(4, 6), LAND, armable=False),
    }
    params = [
        ("MAV_SYS_ID", 1, INT),
        ("COM_OF_LOSS_T", 1.0, REAL),
        ("COM_OBL_RC_ACT", 0, INT),  # 0 Position, 1 Altitude, 2 Manual, 3 Return, 4 Land, 5 Hold
        ("COM_DISARM_LAND", 2.0, REAL),
        ("COM_DISARM_PRFLT", 10.0, REAL),
        ("MPC_THR_HOVER", 0.5, REAL),
        ("MPC_TKO_SPEED", 1.5, REAL),
        ("MPC_LAND_SPEED", 0.7, REAL),
        ("MPC_XY_VEL_MAX", 12.0, REAL),
        ("MIS_TAKEOFF_ALT", 2.5, REAL),
        ("RTL_RETURN_ALT", 30.0, REAL),
        ("SYS_AUTOSTART", 4001, INT),
    ] + _WIND_PARAMS
    return Personality("px4", mavlink.MAV_AUTOPILOT_PX4, modes, "AUTO.LOITER", params,
                       _CAPS | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, True,
                       (1 << 24) | (15 << 16) | (0 << 8) | 255,
                       mode_aliases={"HOLD": "AUTO.LOITER", "POSITION": "POSCTL",
                                     "LAND": "AUTO.LAND", "TAKEOFF": "AUTO.TAKEOFF",
                                     "RTL": "AUTO.RTL", "RETURN": "AUTO.RTL"})


def ardupilot():
    modes = {
        "STABILIZE": Mode("STABILIZE", 0, HOLD),
        "ALT_HOLD": Mode("ALT_HOLD", 2, HOLD),
        "AUTO": Mode("AUTO", 3, HOLD),
        "GUIDED": Mode("GUIDED", 4, OFFBOARD),
        "LOITER": Mode("LOITER", 5, HOLD),
        "RTL": Mode("RTL", 6, RTL, armable=False),
        "LAND": Mode("LAND", 9, LAND, armable=False),
        "POSHOLD": Mode("POSHOLD", 16, HOLD),
        "BRAKE": Mode("BRAKE", 17, HOLD),
        "GUIDED_NOGPS": Mode("GUIDED_NOGPS", 20, OFFBOARD),
    }
    params = [
        ("SYSID_THISMAV", 1, INT),
        ("GUID_OPTIONS", 0, INT),  # bit 3 (8): SET_ATTITUDE_TARGET thrust is thrust, not climb rate
        ("GUID_TIMEOUT", 3.0, REAL),
        ("MOT_THST_HOVER", 0.5, REAL),
        ("PILOT_SPEED_UP", 250, INT),  # cm/s
        ("PILOT_SPEED_DN", 150, INT),  # cm/s
        ("LAND_SPEED", 50, INT),  # cm/s
        ("WPNAV_SPEED_UP", 250, REAL),  # cm/s
        ("DISARM_DELAY", 10, INT),
        ("RTL_ALT", 1500, INT),  # cm
    ] + _WIND_PARAMS
    return Personality("ardupilot", mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, modes, "STABILIZE",
                       params, _CAPS | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST, False,
                       (4 << 24) | (6 << 16) | (0 << 8) | 255)


def personality(name):
    if name == "px4":
        return px4()
    if name == "ardupilot":
        return ardupilot()
    raise ValueError(f"autopilot must be 'px4' or 'ardupilot' (got {name!r})")
