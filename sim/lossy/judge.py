"""What happens to one datagram on the lossy link: lost whole, cut frame by frame, changed, and
how long it waits before it leaves."""

from .frames import DIRECTIONS, LPN, encode_like, mavlink, msg_name, snapshot, split_frames


class Judge:
    """Decides the fate of each datagram a channel receives, drawing from that channel's random
    streams in a fixed order (blackout, datagram loss, then for each frame: frame loss, the
    drop rules, the hook, the corruptions; then the delay), so a seed repeats its decisions.

    Handed the :class:`~sim.lossy.schedule.FaultSchedule` (rules, corruptions, blackouts) and
    the :class:`~sim.lossy.state.LinkState` (where drops, modifications and errors go); holds
    the ``hook`` and the decoders and encoder of the frames.  Its caller holds the link's lock.
    """

    def __init__(self, schedule, state):
        self.schedule = schedule
        self.state = state
        self.hook = None  # f(msg, direction) -> msg (the same, changed, or another) or None
        self._decoder = {d: mavlink.MAVLink(None) for d in DIRECTIONS}
        self._encoder = mavlink.MAVLink(None)

    def datagram(self, ch, data, now):
        """``data`` came in on ``ch`` at monotonic time ``now``: None if nothing of it goes on,
        else (the bytes to send, their frames, the delay before they leave in s)."""
        s = ch.stats
        s.datagrams_in += 1
        s.bytes_in += len(data)
        frames = split_frames(data)
        s.frames_in += len(frames)
        if frames and frames[-1].msgid is None:
            s.unparsed += 1
        if self.schedule.blacked(ch.name, now):
            return self.state.drop(ch, frames, "blackout", now)
        if ch.loss > 0.0 and ch.rng_loss.random() < ch.loss:
            return self.state.drop(ch, frames, "loss", now)
        kept = []
        changed = False
        for f in frames:
            if f.msgid is not None:
                reason = self._frame_fate(ch, f, now)
                if reason is not None:
                    self.state.drop(ch, [f], reason, now, datagram=False)
                    changed = True
                    continue
                if f.new is not None:
                    raw = self._reencode(ch, f, now)
                    if raw is not f.raw:
                        f.raw = raw
                        changed = True
            kept.append(f)
        if frames and not kept:  # every frame dropped on its own: nothing left to send
            s.datagrams_dropped["emptied"] += 1
            return None
        out = b"".join(f.raw for f in kept) if changed else data
        return out, kept, ch.delay()

    def _frame_fate(self, ch, f, now):
        """None if the frame goes on (maybe with ``f.new`` set), else the drop reason."""
        if ch.frame_loss > 0.0 and ch.rng_frame.random() < ch.frame_loss:
            return "frame_loss"
        decoder = self._decoder[ch.name]
        for rule in self.schedule.rules:
            if not rule.active or ch.name not in rule.directions or rule.msgid != f.msgid:
                continue
            if rule.remaining is not None and rule.remaining <= 0:
                continue
            if rule.command is not None or rule.where is not None:
                msg = f.decode(decoder)
                if msg is None:
                    ch.stats.undecodable += 1
                    continue
                if rule.command is not None and getattr(msg, "command", None) != rule.command:
                    continue
                if rule.where is not None:
                    try:
                        if not rule.where(msg):
                            continue
                    except Exception as e:  # noqa: BLE001 (a test's predicate)
                        self.state.error(f"the where= of {rule!r} raised {e!r}: frame kept")
                        continue
            if rule.p < 1.0 and ch.rng_rules.random() >= rule.p:
                continue
            rule.dropped += 1
            if rule.remaining is not None:
                rule.remaining -= 1
            return rule.reason
        hook = self.hook
        if hook is not None:
            msg = f.decode(decoder)
            if msg is not None:
                before = snapshot(msg)
                try:
                    res = hook(msg, ch.name)
                except Exception as e:  # noqa: BLE001 (a test's hook: report, forward as is)
                    self.state.error(f"the hook raised {e!r} on {msg_name(f.msgid)} {ch.name}: "
                                     f"forwarded unchanged")
                    f.msg, f.decoded = None, False  # it may have changed the message half-way
                else:
                    if res is None:
                        return "hook"
                    if res is not msg or snapshot(res) != before:
                        f.new = res
                        f.what.append("hook")
        # forwarded: count it, and change it if a corruption is due
        n = ch._fwd[f.msgid] = ch._fwd[f.msgid] + 1
        if f.msgid == LPN and ch.name == "down":
            ch._lpn_times.append(now)
        for c in self.schedule.corruptions:
            if (c.direction == ch.name and c.msgid == f.msgid and c.first is not None
                    and c.first <= n < c.first + c.count):
                msg = f.new if f.new is not None else f.decode(decoder)
                if msg is None:
                    ch.stats.undecodable += 1
                    ch.stats.refused += 1
                    self.state.error(f"cannot decode {msg_name(f.msgid)} seq {f.seq} {ch.name} "
                                     f"to change {sorted(c.fields)}")
                    continue
                for k, v in c.fields.items():
                    setattr(msg, k, v)
                f.new = msg
                f.what.extend(c.fields)
                c.applied += 1
        return None

    def _reencode(self, ch, f, now):
        name = msg_name(f.msgid)
        if f.signed:
            ch.stats.refused += 1
            self.state.error(f"refused to modify the signed frame {name} seq {f.seq} {ch.name} "
                             f"(it would need the signing key): forwarded unchanged")
            return f.raw
        try:
            raw = encode_like(f.new, f, self._encoder)
        except Exception as e:  # noqa: BLE001 (a hook may return a message that does not pack)
            ch.stats.refused += 1
            self.state.error(f"cannot re-encode {name} seq {f.seq} {ch.name}: {e!r}")
            return f.raw
        if raw == f.raw:
            return f.raw
        self.state.modified(ch, f, now)
        return raw
