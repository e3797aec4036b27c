"""The mission protocol, as far as ground stations need it to connect cleanly: every list
(mission, fence, rally) is empty, an upload of nothing is accepted, anything else refused."""

from pymavlink.dialects.v20 import ardupilotmega as mavlink


def _ack(link, msg, result):
    link.mav.send(mavlink.MAVLink_mission_ack_message(
        msg.get_srcSystem(), msg.get_srcComponent(), result, getattr(msg, "mission_type", 0)))


def on_request_list(link, msg):
    link.mav.send(mavlink.MAVLink_mission_count_message(
        msg.get_srcSystem(), msg.get_srcComponent(), 0, getattr(msg, "mission_type", 0)))


def on_clear_all(link, msg):
    _ack(link, msg, mavlink.MAV_MISSION_ACCEPTED)


def on_count(link, msg):
    _ack(link, msg, mavlink.MAV_MISSION_ACCEPTED if msg.count == 0
         else mavlink.MAV_MISSION_UNSUPPORTED)


def on_request(link, msg):
    """MISSION_REQUEST(_INT): there is no item to send."""
    _ack(link, msg, mavlink.MAV_MISSION_INVALID_SEQUENCE)
