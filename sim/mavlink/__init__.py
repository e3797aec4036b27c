"""The bundled vehicle's MAVLink side, one module per protocol concern (the layout of PX4's
``src/modules/mavlink/``); :class:`sim.server.SitlServer` wires them to the autopilot
(:mod:`sim.autopilot`) and runs them.

- ``link``: a link's socket and peers, signing, per-datagram parsing with its drop counters
  (:class:`~sim.mavlink.link.Stats`), the schedule of its streams and the batching of a step's
  frames; the default ports and rates.
- ``receiver``: each received message to its one handler, after the target check; forwarding.
- ``commands``: COMMAND_LONG / COMMAND_INT and SET_MODE, each answered with a COMMAND_ACK.
- ``parameters``: the parameter set and protocol, the INT32 encodings, the SIM_WIND_* wind.
- ``offboard``: SET_ATTITUDE_TARGET and SET_POSITION_TARGET_LOCAL_NED, checked and handed on.
- ``streams``: one builder per outgoing message, registered under its id.
- ``mission``: the mission protocol with empty lists; ``ftp``: MAVLink FTP declined;
  ``timesync``: TIMESYNC on the vehicle's clock.
"""
