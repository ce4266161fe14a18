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
