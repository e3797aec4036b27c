"""MAVLink FTP, declined: every request is answered with a NAK (file not found), so that clients
that try it first (MAVProxy's parameter download) fall back to the parameter protocol at once."""

from pymavlink.dialects.v20 import ardupilotmega as mavlink

NAK = 129
FILE_NOT_FOUND = 10


def on_ftp(link, msg):
    req = bytes(msg.payload)
    if len(req) < 12:
        return
    seq = (req[0] | (req[1] << 8)) + 1
    nak = bytearray(251)
    nak[0], nak[1] = seq & 0xFF, (seq >> 8) & 0xFF
    nak[2] = req[2]  # session
    nak[3] = NAK
    nak[4] = 1  # size of the error data
    nak[5] = req[3]  # the request's opcode
    nak[12] = FILE_NOT_FOUND
    link.mav.send(mavlink.MAVLink_file_transfer_protocol_message(0, msg.get_srcSystem(),
                                                                 msg.get_srcComponent(),
                                                                 list(nak)))
