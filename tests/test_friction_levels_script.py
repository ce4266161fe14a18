"""scripts/friction_levels.py (round 26 probe): a level shift moves the Coulomb level with the static one following."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import friction_levels as FL  # noqa: E402


def test_a_level_shift_moves_coulomb_and_static_together_and_nothing_else():
    pd = {"friction.coulomb_Nm": 0.2, "friction.static_Nm": 0.22, "spring.preload_Nm": 0.15}
    out = FL._level_shift(pd, 5e-4)
    assert out == pytest.approx({"friction.coulomb_Nm": 0.2005, "friction.static_Nm": 0.2205})


def test_a_level_shift_without_a_static_level_moves_coulomb_only():
    assert FL._level_shift({"friction.coulomb_Nm": 0.2}, -1e-3) == pytest.approx({"friction.coulomb_Nm": 0.199})
