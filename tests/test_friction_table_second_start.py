"""A friction level over angle is fitted a second time from the first fit with its table's mean over the recorded
angles moved into the nominal Coulomb level and the table at 0, and the held-out folds choose
(family_table._second_start; docs/diagnosis-history.md, round 32 l32adf): the nominal Coulomb level and the table's
mean trade, and from the calibration's level the first fit chose a heavy roughness that anchored the knots the
training only passed at the formula (adf@1 3B open s40)."""
from __future__ import annotations

import types

import numpy as np
import pytest

from diagnose_stubs import swing_data
from etb_gym import make_plant
from etb_gym.diagnose import family_table as FT
from etb_gym.diagnose import shapes as S
from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.model import Spec


def test_only_the_friction_level_over_angle_gets_a_second_start():
    base, data = make_plant("3B"), swing_data(40.0, 20.0)
    assert S.family_term("angle_dependent_friction", base, data).second_start
    for cid in ("airflow_torque", "shaft_flux_loss", "stribeck_friction", "supply_drop", "backlash"):
        t = S.family_term(cid, base, data)
        assert t is None or not t.second_start, cid


def _setup():
    base, data = make_plant("3B"), swing_data(40.0, 20.0)
    term = S.family_term("angle_dependent_friction", base, data)
    spec = Spec(base).with_candidate(CANDIDATES["angle_dependent_friction"]).with_candidate(term.candidate())
    k_c = np.array([k for k, (o, _) in enumerate(spec.params) if o == term.id])
    x1 = np.full(len(spec.params), 0.3)             # the first fit: nominal, formula and table all moved
    x1[k_c] = np.linspace(-1.0, 3.0, k_c.size)      # a table that is not flat
    first = types.SimpleNamespace(fit=types.SimpleNamespace(x=x1), problem=None, lams=[1.0], jac=None)
    free = ("nominal", term.id)
    return spec, term, data, k_c, x1, first, free


@pytest.mark.parametrize("h2, second_kept", [(2.0, True), (7.0, False), (4.9, False)])
def test_the_second_start_begins_at_the_first_fits_levels_with_the_table_at_zero_and_the_folds_choose(
        monkeypatch, h2, second_kept):
    spec, term, data, k_c, x1, first, free = _setup()
    started = {}

    def fake_fit(pb, view, log=None):
        started["x"] = pb.x.copy()
        return types.SimpleNamespace(fit=types.SimpleNamespace(x=pb.x + 0.1), problem=pb, lams=[1.0], jac=None)

    monkeypatch.setattr(FT, "fit_penalized", fake_fit)
    monkeypatch.setattr(FT, "heldout_error", lambda pb, data, lams=(), J=None: h2)
    pf, h = FT._second_start(first, 5.0, spec, free, term, data, data, None)
    x0 = started["x"]
    assert np.all(x0[k_c] == 0.0)                                     # the table restarts at 0 ...
    kc = spec.names.index(FT.COULOMB)
    vis = S.visit_time_s(term, data)
    table = np.array([spec.params[k][1].scale * x1[k] for k in k_c])
    shift = float(np.sum(vis * table) / np.sum(vis)) / spec.params[kc][1].scale
    assert abs(shift) > 0.05
    assert x0[kc] == pytest.approx(x1[kc] + shift)                   # its mean where the plate went -> the level
    rest = np.setdiff1d(np.arange(x0.size), np.append(k_c, kc))
    assert np.allclose(x0[rest], x1[rest])                            # ... from the first fit's other values
    assert (pf is not first) == second_kept                           # by MIN_GAIN, else the first fit
    assert h == (h2 if second_kept else 5.0)
