"""The tests' vehicles send only to ports someone holds.

A vehicle started by a test sends its ground-station streams (LOCAL_POSITION_NED at 5 Hz among
them) whether or not anyone reads them.  Sent to a port that was only free when the test asked
for it, they reach whichever test is handed that port next for its client: beside other tests
(pytest-xdist), a lockstep test then read another vehicle's sample as its own and saw its clock
jump (``assert m.time_boot_ms == self.t_ms`` in ``Lockstep.step``).
"""

import errno
import socket

import pytest

from sitl_helpers import Client, start_vehicle


def _held(port):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", port))
    except OSError as e:
        return e.errno == errno.EADDRINUSE
    finally:
        s.close()
    return False


@pytest.mark.parametrize("lockstep", [False, True])
def test_every_port_a_test_vehicle_sends_to_is_held(lockstep):
    srv, port = start_vehicle("px4", lockstep=lockstep)
    c = Client(port)
    try:
        c.heartbeat()
        peers = [p for link in srv.links for p in link.peers]
        assert {link.name for link in srv.links} == {"offboard", "gcs"}
        assert len(peers) == 2 and all(_held(p) for _, p in peers), peers
        gcs = srv.sink.getsockname()[1]
    finally:
        c.close()
        srv.stop()
    assert not _held(gcs)  # given back when the vehicle stops
