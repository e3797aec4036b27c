"""PX4's reasons, as its EVENT messages carry them to an onboard link.

PX4 sends its STATUSTEXTs only on links where a ground station's heartbeat is heard, so a
companion, which heartbeats as an onboard computer, never sees "Disarming denied: not landed".
It does receive PX4's events (MAVLink EVENT, on every link): a 32-bit id and raw arguments whose
texts live in metadata a ground station downloads.  The id is PX4's ``events::ID(name)``:
the 24-bit FNV-1a hash of the event's name, with the autopilot component (1) in the top byte.
This module names the events a companion's flight needs to explain itself, in our own words.
"""

#: event name -> what it tells a companion (the arguments are not decoded)
KNOWN = {
    "commander_disarm_denied_not_landed": "disarming denied: not landed",
    "commander_arm_denied_calibrating": "arming denied: calibrating",
    "commander_arm_denied_not_manual": "arming denied: not in a manual mode",
    "commander_arm_denied_resolve_failures": "arming denied: resolve the failures first",
    "commander_arm_denied_throttle_center": "arming denied: throttle not centred",
    "commander_arm_denied_throttle_high": "arming denied: throttle too high",
    "commander_arming_check_summary": "arming checks report problems (details in a ground station)",
    "commander_armed_by": "armed",
    "commander_disarmed_by": "disarmed",
    "commander_failsafe_enter": "failsafe activated",
    "commander_failsafe_enter_generic": "failsafe activated",
    "commander_failsafe_enter_generic_hold": "failsafe activated: holding",
    "commander_failsafe_enter_generic_warn": "failsafe warning",
    "commander_failsafe_enter_hold": "failsafe activated: holding",
    "commander_failsafe_enter_warn": "failsafe warning",
    "commander_failsafe_enter_autopilot_disengaged": "failsafe: the autopilot disengaged",
    "commander_failsafe_enter_low_bat": "failsafe: low battery",
    "commander_failsafe_enter_crit_bat_warn": "failsafe warning: critical battery",
    "commander_landing_current_pos": "landing at the current position",
    "commander_landing_detected": "landing detected",
    "commander_takeoff_detected": "takeoff detected",
    "commander_mode_fallback_internal": "mode fallback",
    "commander_modeswitch_not_avail": "mode change refused: that mode cannot run now",
    "commander_rtl": "returning to launch",
    "commander_rc_override": "the pilot took over with the sticks",
    "failsafe_rc_override": "the pilot took over with the sticks",
}


def event_id(name):
    """PX4's ``events::ID(name)`` for an autopilot event."""
    h = 0x811C9DC5
    for c in name.encode():
        h = ((h ^ c) * 0x01000193) & 0xFFFFFFFF
    return (h & 0xFFFFFF) | (1 << 24)


_BY_ID = {event_id(name): text for name, text in KNOWN.items()}


WARNING = 4  # PX4's events::Log: Emergency 0 ... Warning 4, Notice 5, Info 6, Debug 7


def describe(event):
    """The text of an EVENT message, or None for an event a companion need not show (an
    unknown one below warning level)."""
    text = _BY_ID.get(event.id)
    if text is None and (event.log_levels & 0x0F) <= WARNING:
        text = (f"PX4 event {event.id:#010x} (its text is in PX4's event metadata: a ground "
                "station shows it)")
    return text


# --- decoding: pymavlink's bundled dialects do not know EVENT (id 410), so its frames arrive as
# unknown messages and are read here, CRC checked, from MAVLink's definition (common.xml):
# id u32, event_time_boot_ms u32, sequence u16, destination_component u8, destination_system u8,
# log_levels u8, arguments u8[40] in wire order
EVENT_ID = 410
_PAYLOAD = 53


def _crc_extra():
    from pymavlink.generator.mavcrc import x25crc

    fields = [("uint32_t", "id", 0), ("uint32_t", "event_time_boot_ms", 0),
              ("uint16_t", "sequence", 0), ("uint8_t", "destination_component", 0),
              ("uint8_t", "destination_system", 0), ("uint8_t", "log_levels", 0),
              ("uint8_t", "arguments", 40)]
    crc = x25crc("EVENT ")
    for ftype, name, n in fields:
        crc.accumulate_str(f"{ftype} {name} ")
        if n:
            crc.accumulate([n])
    return (crc.crc & 0xFF) ^ (crc.crc >> 8)


CRC_EXTRA = _crc_extra()


class Event:
    """The fields of an EVENT message a companion reads."""

    def __init__(self, id, time_boot_ms, sequence, log_levels, system, component):
        self.system = system
        self.component = component
        self.id = id
        self.time_boot_ms = time_boot_ms
        self.sequence = sequence
        self.log_levels = log_levels


def decode(frame):
    """An :class:`Event` from the raw bytes of a MAVLink 2 frame, or None if it is not a valid
    EVENT."""
    import struct

    from pymavlink.generator.mavcrc import x25crc

    b = bytes(frame)
    if len(b) < 12 or b[0] != 0xFD:
        return None
    n = b[1]
    if b[7] | b[8] << 8 | b[9] << 16 != EVENT_ID or len(b) < 12 + n:
        return None
    crc = x25crc(b[1:10 + n])
    crc.accumulate([CRC_EXTRA])
    if crc.crc != (b[10 + n] | b[11 + n] << 8):
        return None
    payload = b[10:10 + n] + bytes(max(0, _PAYLOAD - n))
    eid, t_ms, seq = struct.unpack_from("<IIH", payload)
    return Event(eid, t_ms, seq, payload[12], b[5], b[6])
