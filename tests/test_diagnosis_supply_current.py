"""A supply drop read from the current (discriminate.current_start): a loop hides the drop in the angle, not in the
coil's voltage balance, so the screening starts from the levels the current reads (closed loops, round 31; open
loops along the recorded motion, with the knee read too, round 32)."""
import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.components import effects as fx
from etb_gym.diagnose import discriminate as D
from etb_gym.diagnose import fit as F
from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.explain import extend
from etb_gym.diagnose.model import Spec, prepare
from etb_gym.diagnose.synthetic import make_recording


def _drop_2A(spec, x) -> float:
    """The candidate's drop at 2 A [V] for parameters ``x``."""
    plant, _ = spec.build(x)
    e = next(e for e in plant.effects if getattr(e, "effect_id", None) == "supply_drop")
    q = e.params
    return q.series_resistance_ohm * 2.0 + q.forward_drop_V * np.tanh(2.0 / q.forward_current_A)


def _start(effects, closed=True):
    truth = make_plant("3B", substeps=10, effects=effects)
    rec = make_recording(truth, np.random.default_rng(5), duration_s=2.5, closed=closed, name="rig.csv")
    data = prepare([rec], 12.0, residual="observer" if closed else "replay")
    spec = Spec(make_plant("3B", substeps=10)).with_candidate(CANDIDATES["supply_drop"])
    x0 = extend(np.zeros(len(spec.nominal)), spec)
    x = D.current_start(spec, data, x0, len(spec.nominal))
    cost = [float(np.sum(F.evaluate(spec, data, v) ** 2)) for v in (x0, x)]
    return spec, x0, x, cost


@pytest.mark.parametrize("drop_V", [0.0, 0.3])
def test_the_closed_loops_drop_is_read_from_the_current(drop_V):
    """A closed loop with a drop of 0.3 V at 2 A (0.05 ohm and a forward drop) or none: the start's drop at 2 A is
    the truth's within 40 mV (the candidate's own start: 0.09 V), and its cost is below the start's."""
    eff = [fx.SupplyDrop(series_resistance_ohm=0.05, forward_drop_V=0.2, forward_current_A=0.1)] if drop_V else []
    spec, x0, x, cost = _start(eff)
    assert not np.array_equal(x, x0)
    assert abs(_drop_2A(spec, x) - drop_V) < 0.04, _drop_2A(spec, x)
    assert cost[1] < cost[0]


def _knee(spec, x) -> float:
    return spec.values(x)["supply_drop.forward_current_A"]


@pytest.mark.parametrize("drop_V", [0.0, 0.3])
def test_the_open_loops_drop_is_read_from_the_observers_current(drop_V):
    """An open loop (round 32): the levels are read from the observer's current (the recorded motion's back-EMF),
    the knee at 1, 3 and 10 times its start. A drop of 0.3 V at 2 A whose forward drop builds up over 0.5 A (the
    nameplate's knee: 0.05 A): the start's drop at 2 A is the truth's within 60 mV (measured 47 mV: one chord step
    of the levels; the candidate's own start is 210 mV off) and its knee is read above the nameplate's; no drop:
    the start's drop at 2 A within 60 mV of none."""
    eff = [fx.SupplyDrop(series_resistance_ohm=0.05, forward_drop_V=0.2, forward_current_A=0.5)] if drop_V else []
    spec, x0, x, cost = _start(eff, closed=False)
    assert not np.array_equal(x, x0)
    assert abs(_drop_2A(spec, x) - drop_V) < 0.06, _drop_2A(spec, x)     # (the own start: 0.09 V)
    assert cost[1] < cost[0]
    if drop_V:
        assert _knee(spec, x) > 0.1, _knee(spec, x)


def test_the_closed_loop_keeps_the_nameplates_knee():
    """A closed loop's current holds away from 0 A: only the levels are read, the knee stays at its start."""
    eff = [fx.SupplyDrop(series_resistance_ohm=0.05, forward_drop_V=0.2, forward_current_A=0.5)]
    spec, x0, x, _ = _start(eff)
    assert _knee(spec, x) == pytest.approx(_knee(spec, x0))


class _Runner:
    """The screening's tasks answered without simulating: the RSS a start leads to (``rss_of``)."""

    def __init__(self, rss_of):
        self.rss_of, self.starts = rss_of, []

    def map(self, tasks, progress=None):
        out = []
        for _, _, _, ids, x0, *_ in tasks:
            self.starts.append((ids, np.array(x0)))
            out.append((np.array(x0), self.rss_of(ids, x0), 6000, None, 1, 1.0, None))
        return out


@pytest.mark.parametrize("pinned_rss, kept", [(5000.0, "pinned"), (9000.0, "own")])
def test_the_screening_keeps_the_better_of_the_two_starts(monkeypatch, pinned_rss, kept):
    """explain._screen fits a supply drop from its own start and from the one read from the current, and keeps the
    fit that ends lower (a second start, not a replacement)."""
    from etb_gym.diagnose import explain as E
    base = make_plant("3B", substeps=10)
    spec = Spec(base)
    cur = F.FitResult(spec, np.zeros(len(spec.nominal)), 10000.0, 6000, None, 1)
    marker = 0.123

    def fake_start(sp, data, x0, n_old, log=None):
        x = np.array(x0, float)
        x[n_old] = marker
        return x

    monkeypatch.setattr(D, "current_start", fake_start)

    def rss_of(ids, x0):
        if "supply_drop" not in ids:
            return 10000.0
        return pinned_rss if x0[len(spec.nominal)] == marker else 8000.0

    runner = _Runner(rss_of)
    ctx = E._Ctx(None, runner, base, base.to_dict(), spec.nominal, None, lambda *a: None, None)
    _, screened = E._screen(ctx, cur, ["supply_drop", "coil_heating"], 0)
    fr = {c: f for _, c, f in screened}
    assert len(runner.starts) == 4                          # the current model, two supply-drop starts, the heating
    assert fr["supply_drop"].rss == (pinned_rss if kept == "pinned" else 8000.0)
    assert fr["coil_heating"].rss == 10000.0
