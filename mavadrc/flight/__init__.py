"""A flight over MAVLink: the loop, its phases, the supervisor and failsafes, records."""
