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


# in real time the vehicle's first heartbeat comes on its own clock
@pytest.mark.parametrize("lockstep", [pytest.param(False, marks=pytest.mark.realtime), True])
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


@pytest.mark.parametrize("kind", ["udp", "tcp"])
def test_a_port_chosen_free_is_never_an_ephemeral_one(kind):
    """A port chosen free is released until its user binds it; from below the kernel's
    ephemeral range, no socket bound to port 0 meanwhile (a lossy link's, a vehicle's, another
    worker's) can be handed it.  Once, a proxy's own socket took the companion's port and the
    companion found it in use."""
    from mavadrc.flight import embedded

    span = embedded._ephemeral_range()
    if span is None or span[0] <= embedded.PORT_FLOOR + 1000:
        pytest.skip("no ephemeral range to stay below on this machine")
    choose = embedded.free_udp_port if kind == "udp" else embedded.free_tcp_port
    sock_type = socket.SOCK_DGRAM if kind == "udp" else socket.SOCK_STREAM
    ports = [choose() for _ in range(50)]
    assert all(embedded.PORT_FLOOR <= p < span[0] for p in ports), ports
    assert len(set(ports)) > 40  # drawn at random, not one port handed to every caller
    for p in ports[:5]:
        s = socket.socket(socket.AF_INET, sock_type)
        s.bind(("127.0.0.1", p))  # and free to take
        s.close()
