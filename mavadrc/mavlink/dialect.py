"""The MAVLink dialect every module of the link speaks: MAVLink 2, pymavlink's ``mavutil`` and
its ``mavlink`` module as ``M``.  Import them from here: the environment must ask for MAVLink 2
before pymavlink loads its dialect."""

import os

os.environ.setdefault("MAVLINK20", "1")  # speak MAVLink 2; must precede pymavlink's dialect import

from pymavlink import mavutil  # noqa: E402

M = mavutil.mavlink
