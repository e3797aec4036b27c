"""The link model's decisions: deterministic under the seed, the loss and delays asked for,
blackouts, and the companion's side of the discrete link."""

import numpy as np
import pytest

from sim.link_model import LOST, Delivery, LinkModel, Way, link_from_section
from sim.yamlio import ConfigError, Section


def test_the_same_seed_makes_the_same_decisions_whatever_is_asked_first():
    m = LinkModel(Way(latency_s=0.02, jitter_s=0.01, loss=0.1), Way(loss=0.05))
    a = m.schedule(7, 0.01)
    b = m.schedule(7, 0.01)
    assert [a.down(k) for k in range(500)] == list(b.arrays(500)[0])
    assert [a.up(k) for k in range(500)] == list(b.arrays(500)[1])
    c = m.schedule(8, 0.01)
    assert list(c.arrays(500)[0]) != list(b.arrays(500)[0])


def test_loss_and_delay_as_asked():
    m = LinkModel(Way(latency_s=0.015, jitter_s=0.01, loss=0.2))
    down, up = m.schedule(1, 0.01).arrays(20000)
    lost = down == LOST
    assert lost.mean() == pytest.approx(0.2, abs=0.01)
    # 15-25 ms at 10 ms periods: used at the second or third period after it was taken
    kept = down[~lost]
    assert set(np.unique(kept)) == {2, 3} and (kept == 2).mean() == pytest.approx(0.5, abs=0.02)
    assert (up == 0).all()  # a perfect direction


def test_blackouts_cut_both_ways_for_their_span():
    m = LinkModel(blackouts=((1.0, 0.5),))
    down, up = m.schedule(0, 0.01, ).arrays(300)
    t = np.arange(300) * 0.01
    dark = (t >= 1.0 - 1e-9) & (t < 1.5 - 1e-9)
    assert (down[dark] == LOST).all() and (up[dark] == LOST).all()
    assert (down[~dark] == 0).all()


def test_the_companion_gets_the_newest_sample_once():
    d = Delivery()
    d.arrive(0, 2)  # arrives at 2
    d.arrive(1, 0)  # arrives at 1
    d.arrive(2, LOST)
    d.arrive(3, 0)
    assert d.take(0) is None
    assert d.take(1) == 1
    assert d.take(2) is None  # sample 0 arrives now, but 1 is newer and already taken
    assert d.take(3) == 3
    assert d.take(4) is None


def test_a_link_section_is_checked():
    sec = Section({"down": {"latency_s": 0.05, "loss": 0.1}, "blackouts": [[3, 1]]}, "f.yaml")
    m = link_from_section(sec)
    assert m.down.latency_s == 0.05 and m.blackouts == ((3.0, 1.0),) and m.up.perfect
    with pytest.raises(ConfigError, match="loss"):
        link_from_section(Section({"up": {"loss": 1.5}}, "f.yaml"))
    with pytest.raises(ConfigError, match="blackouts"):
        link_from_section(Section({"blackouts": [[3]]}, "f.yaml"))
    with pytest.raises(ConfigError, match="latncy_s"):
        link_from_section(Section({"down": {"latncy_s": 0.1}}, "f.yaml"))
