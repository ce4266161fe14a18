"""scripts/friction_speed_curve.py (analysis only, round 28): the steady friction over speed of a plant."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

from etb_gym import make_plant
from etb_gym.components import effects as fx

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import friction_speed_curve as FSC  # noqa: E402


def test_the_steady_friction_falls_from_the_static_to_the_coulomb_level_and_an_effect_adds_its_stiction():
    base = make_plant("3B")
    q = base.friction.params
    curve = lambda w, tc, ts, ws: tc + (ts - tc) * math.exp(-math.sqrt(w / ws))     # eq. 28
    slow, fast = FSC.steady_friction(base, 1e-3), FSC.steady_friction(base, 30.0)
    assert slow == pytest.approx(curve(1e-3, q.coulomb_Nm, q.static_Nm, q.stribeck_velocity_rad_s)
                                 + q.viscous_Nm_s_per_rad * 1e-3, abs=1e-5)
    assert fast == pytest.approx(q.coulomb_Nm + q.viscous_Nm_s_per_rad * 30.0, abs=1e-3)
    assert FSC.steady_friction(base, -1e-3) == pytest.approx(slow, abs=1e-9)       # against the motion both ways
    plant = base.replace(effects=[fx.StribeckFriction(stiction_Nm=0.03, stribeck_velocity_rad_s=0.1)])
    assert FSC.steady_friction(plant, 1e-3) - slow == pytest.approx(curve(1e-3, 0.0, 0.03, 0.1), abs=1e-5)
    assert FSC.steady_friction(plant, 30.0) - fast == pytest.approx(0.0, abs=1e-3)
