"""The lossy link's sockets and its thread: datagrams read from either side, judged, and sent
on at once or held until their delay is over."""

import heapq
import logging
import select
import socket
import threading
import time

log = logging.getLogger("mavadrc.lossy")


class Transport:
    """Two UDP sockets (the vehicle's side bound to ``vehicle_port``, the companion's to a free
    port), the proxy thread that reads them, and the queue of datagrams waiting out a delay.

    Handed the two channels, the link's lock (held while a datagram is judged and while the
    queue changes), and what it calls: ``judge(ch, data, now)`` -> None or (bytes, frames,
    delay s), ``drop(ch, frames, reason, t)`` for what it cannot deliver, ``error(text)`` and
    ``blacked(direction, t)`` (a datagram due in a blackout is lost).  ``vehicle_addr`` is the
    address the vehicle last sent from (up goes there), ``companion_addr`` where down goes."""

    def __init__(self, host, vehicle_port, companion_addr, vehicle_addr, *, down, up, lock,
                 judge, drop, error, blacked):
        self.host = host
        self.companion_addr = companion_addr
        self.vehicle_addr = vehicle_addr
        self.down, self.up = down, up
        self._lock = lock
        self._judge, self._drop, self._error, self._blacked = judge, drop, error, blacked
        self._heap = []
        self._order = 0
        self._running = False
        self._thread = None
        self._vsock = self._socket(vehicle_port)
        self._csock = self._socket(0)
        self.vehicle_port = self._vsock.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)

    def _socket(self, port):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            try:
                s.setsockopt(socket.SOL_SOCKET, opt, 1 << 20)
            except OSError:
                pass
        s.bind((self.host, port))
        s.setblocking(False)
        return s

    @property
    def companion_side_port(self):
        """The port datagrams leave from to the companion (the companion answers there)."""
        return self._csock.getsockname()[1]

    @property
    def started(self):
        return self._thread is not None

    # --- life cycle ------------------------------------------------------------------------------

    def start(self):
        self._running = True
        self._thread = threading.Thread(target=self._run, name="lossy-link", daemon=True)
        self._thread.start()

    def stop(self):
        """End the thread, close the sockets, and drop what is still in flight (``"stopped"``)."""
        self._running = False
        if self._thread is not None:
            try:
                self._wake_w.send(b"x")
            except OSError:
                pass
            self._thread.join(timeout=5.0)
        for s in (self._vsock, self._csock, self._wake_r, self._wake_w):
            s.close()
        with self._lock:
            t = time.monotonic()
            for _, _, ch, _, frames in self._heap:  # still in flight: lost with the link
                self._drop(ch, frames, "stopped", t)
                ch.stats.in_flight -= 1
            self._heap.clear()

    # --- the loop --------------------------------------------------------------------------------

    def _run(self):
        socks = [self._vsock, self._csock, self._wake_r]
        while self._running:
            with self._lock:
                timeout = max(0.0, self._heap[0][0] - time.monotonic()) if self._heap else None
            try:
                readable, _, _ = select.select(socks, [], [], timeout)
            except (OSError, ValueError):
                break
            if not self._running:
                break
            if self._heap:
                self._deliver_due()
            if self._wake_r in readable:
                try:
                    self._wake_r.recv(64)
                except OSError:
                    pass
            if self._vsock in readable:
                self._drain(self._vsock, self.down)
            if self._csock in readable:
                self._drain(self._csock, self.up)

    def _drain(self, sock, ch):
        while True:
            try:
                data, addr = sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionRefusedError:  # an ICMP error for an earlier send: ignore it
                continue
            except OSError:
                return
            with self._lock:
                if ch is self.down:
                    self.vehicle_addr = addr
                try:
                    self._forward(ch, data, time.monotonic())
                except Exception as e:  # noqa: BLE001 (a bug or a test's callable: keep going)
                    log.exception("lossy link: forwarding a datagram %s", ch.name)
                    self._error(f"forwarding a datagram {ch.name} failed: {e!r}")

    def _forward(self, ch, data, now):
        verdict = self._judge(ch, data, now)
        if verdict is None:
            return
        out, kept, delay = verdict
        if delay <= 0.0:  # due now: after whatever is overdue, before what is still in flight
            if self._heap:
                self._deliver_due()
            self._send(ch, out, kept, now)
        else:
            self._order += 1
            heapq.heappush(self._heap, (now + delay, self._order, ch, out, kept))
            ch.stats.in_flight += 1

    def _deliver_due(self):
        with self._lock:
            now = time.monotonic()
            while self._heap and self._heap[0][0] <= now:
                due, _, ch, out, frames = heapq.heappop(self._heap)
                ch.stats.in_flight -= 1
                if self._blacked(ch.name, due):
                    self._drop(ch, frames, "blackout", due)
                else:
                    self._send(ch, out, frames, due)

    def _send(self, ch, out, frames, t):
        if ch is self.down:
            sock, addr = self._csock, self.companion_addr
        else:
            sock, addr = self._vsock, self.vehicle_addr
            if addr is None:
                return self._drop(ch, frames, "no_vehicle", t)
        try:
            sock.sendto(out, addr)
        except OSError:
            return self._drop(ch, frames, "send_error", t)
        s = ch.stats
        s.datagrams_out += 1
        s.frames_out += len(frames)
        s.bytes_out += len(out)
