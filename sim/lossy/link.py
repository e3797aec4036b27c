"""The lossy link as its users hold it: one object with its two channels, its faults, its
statistics and its life cycle, made of the pieces that do the work (see the package's doc)."""

import math
import threading
import time

from .channel import Channel
from .frames import LPN, msg_id, named_directions
from .judge import Judge
from .schedule import FaultSchedule
from .state import LinkState
from .transport import Transport


class LossyLinkError(RuntimeError):
    """A fault the proxy was asked for but refused (a signed frame, an undecodable frame, a
    hook that raised), raised by :meth:`LossyLink.stop`."""


class LossyLink:
    """A UDP proxy between a vehicle's offboard link and a companion, with faults.

    ``LossyLink(companion_port, vehicle_port=0, host="127.0.0.1", seed=0, vehicle_addr=None)``:
    the companion listens on ``companion_port`` (``udpin:HOST:PORT``, see ``companion_url``);
    the vehicle must send to ``vehicle_port`` (bound now; 0 picks a free port, read it back from
    the attribute).  Datagrams from the companion go to the address the vehicle last sent from
    (or ``vehicle_addr`` until it has sent), from the vehicle-side socket, so the vehicle sees
    its configured peer answering.  ``start()`` runs the proxy in a thread, ``stop()`` ends it;
    it is also a context manager.

    Made of a :class:`~sim.lossy.transport.Transport` (sockets, thread, delivery queue), a
    :class:`~sim.lossy.schedule.FaultSchedule` (rules, blackouts, corruptions, marks), a
    :class:`~sim.lossy.judge.Judge` (what happens to one datagram, and the ``hook``) and a
    :class:`~sim.lossy.state.LinkState` (start, drops, errors, counters), sharing one lock.
    """

    def __init__(self, companion_port, *, vehicle_port=0, host="127.0.0.1", seed=0,
                 vehicle_addr=None):
        self.host = host
        self.companion_port = int(companion_port)
        self.seed = seed
        self.down = Channel("down", seed)
        self.up = Channel("up", seed)
        self._lock = threading.RLock()
        self._state = LinkState(self.down, self.up)
        self._schedule = FaultSchedule(self.down, self.up, self._lock)
        self._judge = Judge(self._schedule, self._state)
        self._transport = Transport(
            host, vehicle_port, (host, self.companion_port),
            tuple(vehicle_addr) if vehicle_addr is not None else None,
            down=self.down, up=self.up, lock=self._lock, judge=self._judge.datagram,
            drop=self._state.drop, error=self._state.error, blacked=self._schedule.blacked)
        self.vehicle_port = self._transport.vehicle_port

    # --- what the pieces hold --------------------------------------------------------------------

    @property
    def hook(self):
        """``f(msg, direction) -> msg`` (the same, changed, or another) or None (dropped): sees
        every decodable frame; None (the default): no hook."""
        return self._judge.hook

    @hook.setter
    def hook(self, f):
        self._judge.hook = f

    @property
    def vehicle_addr(self):
        """Where datagrams up go: the address the vehicle last sent from."""
        return self._transport.vehicle_addr

    @vehicle_addr.setter
    def vehicle_addr(self, addr):
        self._transport.vehicle_addr = addr

    @property
    def companion_addr(self):
        """Where datagrams down go: (host, companion_port)."""
        return self._transport.companion_addr

    @companion_addr.setter
    def companion_addr(self, addr):
        self._transport.companion_addr = addr

    @property
    def errors(self):
        """The faults refused and the callables that raised, as text (see :meth:`stop`)."""
        return self._state.errors

    @property
    def rules(self):
        return self._schedule.rules

    @property
    def blackouts(self):
        return self._schedule.blackouts

    @property
    def corruptions(self):
        return self._schedule.corruptions

    @property
    def marks(self):
        return self._schedule.marks

    # --- endpoints and life cycle ----------------------------------------------------------------

    @property
    def companion_url(self):
        """The connection string the companion listens with, e.g. ``udpin:127.0.0.1:14540``."""
        return f"udpin:{self.host}:{self.companion_port}"

    @property
    def companion_side_port(self):
        """The port the proxy sends to the companion from (the companion answers there)."""
        return self._transport.companion_side_port

    @property
    def start_time(self):
        """``time.monotonic()`` at :meth:`start` (None before): drop and modification records
        carry ``t`` relative to it, blackout windows are in monotonic time."""
        return self._state.start_t

    @property
    def channels(self):
        return {"down": self.down, "up": self.up}

    def start(self):
        with self._lock:
            if self._transport.started:
                raise RuntimeError("the proxy is already started")
            self._state.start_t = time.monotonic()
            self._schedule.started(self._state.start_t)
        self._transport.start()
        return self

    def stop(self, check=True):
        """End the proxy and close its sockets (datagrams still waiting out their latency are
        dropped, reason ``"stopped"``); with ``check``, raise :class:`LossyLinkError` if a fault
        was refused or the hook raised."""
        self._transport.stop()
        if check and self.errors:
            raise LossyLinkError("; ".join(self.errors))

    def __enter__(self):
        if not self._transport.started:
            self.start()
        return self

    def __exit__(self, exc_type, exc, tb):
        self.stop(check=exc_type is None)
        return False

    def now(self):
        """Seconds since the proxy started."""
        t0 = self._state.start_t
        return time.monotonic() - t0 if t0 is not None else 0.0

    # --- faults ----------------------------------------------------------------------------------

    def mark(self, name="mark"):
        """Record a reference point ``name`` (now, and the messages forwarded so far) for
        :meth:`blackout` and :meth:`corrupt` (``after=name``); returns the proxy time (s).
        Faults already anchored keep their anchor; marking again only moves later ones."""
        return self._schedule.mark(name)

    def set(self, direction="both", **faults):
        """Set channel faults in one direction or both: ``link.set("both", loss=0.1)``."""
        for d in named_directions(direction):
            self.channels[d].set(**faults)
        return self

    def reseed(self, seed):
        """Restart the random streams of both directions from ``seed``."""
        with self._lock:
            self.seed = seed
            self.down.reseed(seed)
            self.up.reseed(seed)

    def blackout(self, start_s, duration_s, *, direction="both", after="start", after_lpn=0):
        """Nothing passes in ``direction`` from ``start_s`` to ``start_s + duration_s`` seconds
        after the reference: ``after`` is ``"start"`` (the proxy's start), ``"now"``, or the name
        of a :meth:`mark` (pending until it is made); with ``after_lpn=N`` the reference is the
        moment the N-th LOCAL_POSITION_NED after that point is forwarded down (it passes; the
        window can begin right after it).  Returns the :class:`Blackout`."""
        return self._schedule.blackout(start_s, duration_s, direction, after, after_lpn)

    def corrupt(self, msg_type, nth, fields, *, direction="down", after="start", count=1):
        """Give the ``nth`` (1 = the first) message of ``msg_type`` forwarded in ``direction``
        after the reference (``"start"``, ``"now"`` or a mark name, as for :meth:`blackout`)
        the ``fields`` values (a dict), and the ``count - 1`` next ones too.  Messages dropped
        by other faults are not counted.  Returns the :class:`Corruption`."""
        return self._schedule.corrupt(msg_type, nth, fields, direction, after, count)

    def inject_nan(self, nth=1, fields=("x",), *, after="start", count=1):
        """NaN in ``fields`` of the ``nth`` LOCAL_POSITION_NED forwarded down (see
        :meth:`corrupt`)."""
        return self.corrupt(LPN, nth, {f: math.nan for f in fields}, direction="down",
                            after=after, count=count)

    def drop_messages(self, msg_type, p=1.0, *, direction="both", command=None, n=None,
                      where=None, reason="rule"):
        """Drop frames of ``msg_type`` in ``direction`` with probability ``p``; only those whose
        ``command`` field is ``command`` if given (COMMAND_LONG, COMMAND_INT, COMMAND_ACK), and
        for which ``where(msg)`` is true if given; at most ``n`` of them (None: no limit).
        Returns the :class:`Rule`."""
        return self._schedule.drop_messages(msg_type, p, direction, command, n, where, reason)

    def drop_command(self, command, n=1):
        """Drop the next ``n`` COMMAND_LONG of ``command`` going up (to the vehicle)."""
        return self.drop_messages("COMMAND_LONG", direction="up", command=command, n=n,
                                  reason="command")

    def drop_ack(self, command, n=1):
        """Drop the next ``n`` COMMAND_ACK of ``command`` going down (to the companion)."""
        return self.drop_messages("COMMAND_ACK", direction="down", command=command, n=n,
                                  reason="ack")

    def remove(self, item):
        """Lift a rule, blackout or corruption."""
        self._schedule.remove(item)

    def clear(self):
        """No faults at all (channels, rules, blackouts, corruptions, hook); stats are kept."""
        with self._lock:
            self.down.clear()
            self.up.clear()
            self._schedule.clear()
            self._judge.hook = None

    # --- queries ---------------------------------------------------------------------------------

    def forwarded(self, msg_type="LOCAL_POSITION_NED", direction="down"):
        """How many frames of ``msg_type`` have been forwarded in ``direction`` (decided, not
        necessarily delivered yet if there is latency)."""
        (d,) = named_directions(direction)
        with self._lock:
            return self.channels[d]._fwd[msg_id(msg_type)]

    def in_blackout(self, direction, t=None):
        """Whether a blackout holds ``direction`` at monotonic time ``t`` (now)."""
        t = time.monotonic() if t is None else t
        with self._lock:
            return self._schedule.blacked(direction, t)

    @property
    def drops(self):
        """Every drop of both directions, in time order."""
        with self._lock:
            return self._state.drops()

    def stats(self):
        """A snapshot: {"down": {...}, "up": {...}} of the counters (without the logs)."""
        with self._lock:
            return self._state.snapshot()
