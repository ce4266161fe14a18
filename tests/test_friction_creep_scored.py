"""A friction table over speed is kept, on an open-loop recording, by the continuous replay's held-out folds
(shapes.creep_scored; docs/diagnosis-rounds/round28-w28stribeck.md): its low-speed knots set where a held plate
sticks, which the fit's restarted segments barely see. The fits and scores below are stand-ins: the choice only."""
from __future__ import annotations

import numpy as np

from diagnose_stubs import swing_data
from etb_gym import make_plant
from etb_gym.diagnose import fit as F
from etb_gym.diagnose import shapes as S
from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.model import Spec, prepare, restart_view
from etb_gym.diagnose.synthetic import make_recording


def test_only_friction_tables_over_speed_are_scored_on_the_continuous_replay():
    base, data = make_plant("3B"), swing_data(40.0, 20.0)
    strib = S.family_terms("stribeck_friction", base, data)
    assert strib and all(S.creep_scored(t) for t in strib)
    assert not S.creep_scored(S.family_term("angle_dependent_friction", base, data))
    assert not S.creep_scored(S.family_term("airflow_torque", base, data))


def _run(monkeypatch, cid):
    base = make_plant("3B", substeps=20)
    data = prepare([make_recording(base, np.random.default_rng(0), duration_s=0.5, name="r.csv")], 12.0)
    fr = F.FitResult(Spec(base).with_candidate(CANDIDATES[cid]), np.zeros(0), 1.0, 10, None, 0)
    fr.x = np.zeros(len(fr.spec.params))
    scored = []

    def fake_fit(pb, view, log=None):
        x = pb.x.copy()
        x[-1] = 1.0 if view.continuity else 2.0        # marks which view's fit it is
        return S.PenalizedFit(F.FitResult(pb.spec, x, 1.0, 10, None, 0), [1.0], [1.0], None, pb, [])

    def fake_heldout(pb, d, lams=(), J=None, jac_substeps=S.JAC_SUBSTEPS):
        # the fit's view: the table gains 2 % (not kept by MIN_GAIN); the continuous replay: 20 %, for the
        # continuous view's fit only
        table = len(pb.x) > len(fr.x)
        scored.append(d.continuity)
        if not d.continuity:
            return 0.98 if table else 1.0
        return (0.8 if float(pb.x[-1]) == 1.0 else 0.99) if table else 1.0

    monkeypatch.setattr(S, "fit_penalized", fake_fit)
    monkeypatch.setattr(S, "heldout_error", fake_heldout)
    return S.refine_family(fr, cid, restart_view(data), log=lambda *a: None), scored


def test_a_speed_friction_table_is_kept_by_the_continuous_replay(monkeypatch):
    ref, scored = _run(monkeypatch, "stribeck_friction")
    assert True in scored
    assert ref.kept and ref.fit.x[-1] == 1.0          # the continuous view's fit, kept on its folds
    assert ref.heldout_formula == 1.0 and ref.heldout_map == 0.98     # refine compares the fit view's errors


def test_other_tables_keep_the_fit_view_decision(monkeypatch):
    ref, scored = _run(monkeypatch, "airflow_torque")
    assert not ref.kept and True not in scored
