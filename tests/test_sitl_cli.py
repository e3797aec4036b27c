"""`mavadrc sitl` (`python -m sim`) as a user starts it, in a process of its own."""

import os
import socket
import subprocess
import sys
import time

import pytest

from sitl_helpers import free_udp_port


def free_instance():
    """An instance number whose two local ports (14580+N, 18570+N) are free right now."""
    for n in range(60, 400):
        if all(_free(base + n) for base in (14580, 18570)):
            return n
    pytest.skip("no instance with both local ports free")


def _free(port):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", port))
        return True
    except OSError:
        return False
    finally:
        s.close()


@pytest.mark.parametrize("link, base, option", [("offboard", 14580, "--bind-offboard"),
                                                ("gcs", 18570, "--bind-gcs")])
def test_a_local_port_in_use_fails_at_once_naming_the_port_and_the_option(tmp_path, link, base,
                                                                          option):
    """Issue 12 item 8: a UDP port already in use ends the command at once, before the numba
    kernels are compiled (its fresh cache stays empty), with one line that names the port and
    the options that choose another, and no traceback."""
    n = free_instance()
    port = base + n
    held = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    held.bind(("127.0.0.1", port))
    cache = tmp_path / "numba"
    cache.mkdir()
    try:
        t0 = time.monotonic()
        p = subprocess.run([sys.executable, "-m", "sim", "--instance", str(n),
                            "--offboard-port", str(free_udp_port()),
                            "--gcs-port", str(free_udp_port()), "--duration", "30"],
                           capture_output=True, text=True, timeout=120,
                           env=dict(os.environ, NUMBA_CACHE_DIR=str(cache)))
        elapsed = time.monotonic() - t0
    finally:
        held.close()
    out = p.stdout + p.stderr
    assert p.returncode != 0
    assert f"UDP port {port}" in p.stderr and f"the {link} link" in p.stderr, out
    assert option in p.stderr and "--instance" in p.stderr, out
    assert "Traceback" not in out
    assert [f for _, _, files in os.walk(cache) for f in files] == []  # nothing compiled
    assert elapsed < 10.0
