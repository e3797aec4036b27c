"""Test-session setup shared by every test file."""

import os
import signal

# MAVLink 2 before any test module imports pymavlink (which picks its dialect once, on import),
# whatever order a file's imports come in
os.environ.setdefault("MAVLINK20", "1")

# The Ctrl-C tests send SIGINT to a command they started, as a terminal does.  A shell starts a
# background job (`pytest ... &` with no job control, as CI scripts often do) with SIGINT
# ignored, and an ignored signal stays ignored across exec: the command would never see the
# Ctrl-C.  A terminal's commands have SIGINT at its default, so the session restores that here
# (a handler is reset to the default in the commands it starts; an ignored signal is not).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
