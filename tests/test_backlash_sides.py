"""The free play's two sides (round 29): b above limp-home, r*b below it (r = 1: the symmetric play)."""
import dataclasses

import numpy as np
import pytest

from etb_gym.components import effects as fx
from etb_gym.diagnose import truth_shapes as ts
from etb_gym.diagnose.candidates import CANDIDATES


def _vector(params):
    return np.array([float(getattr(params, f.name)) for f in dataclasses.fields(params)])


def test_a_centred_play_is_the_asymmetric_play():
    """Checked against an independent asymmetric play (the proof's hidden truth shape, used here as a reference
    implementation only): the same torque at every angle and speed; the symmetric play of the same total width
    is another torque."""
    b_open, b_close = 0.012, 0.004
    play = fx.Backlash(play_rad=b_open, closing_ratio=b_close / b_open)
    sym = fx.Backlash(play_rad=b_open)
    ref = ts.SoftBacklash(play_rad=b_open, closing_play_rad=b_close, profile=1.0)
    s, ds = np.zeros(1), np.zeros(1)
    worst, apart = 0.0, 0.0
    for phi in np.linspace(0.0, 0.12, 601):
        for omega in (-2.0, 0.0, 2.0):
            t_ref = ref.kernel(0.0, phi, omega, 0.0, 0.0, s, _vector(ref.params), ds)[0]
            worst = max(worst, abs(play.kernel(0.0, phi, omega, 0.0, 0.0, s, _vector(play.params), ds)[0] - t_ref))
            apart = max(apart, abs(sym.kernel(0.0, phi, omega, 0.0, 0.0, s, _vector(sym.params), ds)[0] - t_ref))
    assert worst < 1e-12 and apart > 1e-3


def test_the_candidate_starts_symmetric_and_fits_the_closing_side():
    """The closing share starts at 1: the screening and the play's scan see the symmetric play, and a recording
    that never passes below limp-home leaves the unseen side mirroring the seen one."""
    c = CANDIDATES["backlash"]
    assert [p.name for p in c.fit] == ["play_rad", "closing_ratio"]
    assert c.fit[1].init == 1.0 and c.fit[1].lower == 0.0 < 1.0 < c.fit[1].upper
    assert dict(c.off) == {"play_rad": 0.0, "closing_ratio": 1.0}
    with pytest.raises(ValueError, match="BacklashParams.closing_ratio"):
        fx.Backlash(closing_ratio=-0.5)


def _unseen(monkeypatch, below_rad, cost=lambda x: 100.0):
    """closed_twin.unseen_closing_play on the 3B plant with the free play at its start (b 0.004 rad, r 1) and
    recordings whose lowest angle is ``below_rad`` under limp-home; the fit's cost a stand-in (100 residuals)."""
    import math
    from types import SimpleNamespace as NS

    from etb_gym.diagnose import closed_twin as CT
    from etb_gym.diagnose.fit import FitResult, Spec
    from etb_gym.plant import make_plant
    spec = Spec(make_plant("3B"), (CANDIDATES["backlash"],))
    final = FitResult(spec, np.zeros(len(spec.params)), 0.0, 0, None, 0)
    lh = math.degrees(spec.base.limp_home_rad)
    angles = np.linspace(lh - math.degrees(below_rad), lh + 40.0, 300)
    monkeypatch.setattr(CT, "_replay_cost", lambda fr, d: (cost(fr.x), 100))
    note = {}
    out = CT.unseen_closing_play(final, NS(recs=[NS(rec=NS(angle_deg=angles))]), note)
    return final, out, note.get("unseen_closing_play")


def _ratio(fr):
    k = [i for i, (o, p) in enumerate(fr.spec.params) if p.name == "closing_ratio"][0]
    p = fr.spec.params[k][1]
    return p.init + p.scale * fr.x[k]


def test_a_closing_side_never_reached_takes_the_middle_of_what_the_data_allow(monkeypatch):
    """Recordings 0.0005 rad below limp-home, the play 0.004 rad mirrored (r 1): the closing play lies somewhere
    in [0.0005, 0.004]; the twin takes the middle, r = (0.125 + 1) / 2."""
    final, out, info = _unseen(monkeypatch, 0.0005)
    assert info["kept"] and _ratio(final) == 1.0
    assert _ratio(out) == pytest.approx(0.5625, rel=1e-9)


def test_a_closing_side_the_recordings_passed_keeps_its_fit(monkeypatch):
    final, out, info = _unseen(monkeypatch, 0.01)            # 0.01 rad below limp-home: past the edge at 0.004
    assert out is final and info is None


def test_the_edit_is_refused_where_the_fits_cost_rises_by_more_than_its_noise(monkeypatch):
    final, out, info = _unseen(monkeypatch, 0.0005, cost=lambda x: 100.0 if _ratio_x(x) > 0.9 else 200.0)
    assert out is final and not info["kept"]


def _ratio_x(x):
    return 1.0 + 0.25 * x[-1]         # closing_ratio: init 1, scale 0.25, the spec's last parameter
