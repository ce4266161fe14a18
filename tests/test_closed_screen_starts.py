"""explain._screen in a closed loop: each candidate also fitted from the nameplate's nominal levels (round 25)."""
from types import SimpleNamespace

import numpy as np

from etb_gym.diagnose import explain as E
from etb_gym.diagnose import fit as F
from etb_gym.diagnose.model import Spec
from etb_gym.plant import make_plant


class _Runner:
    """Answers every fit task with an RSS that depends on where its nominal levels start."""

    def __init__(self):
        self.tasks = []

    def map(self, tasks, progress=None):
        self.tasks = list(tasks)
        out = []
        for t in tasks:
            x0 = np.array(t[4], float)
            from_nameplate = len(t[3]) > 0 and not np.any(x0[:3])
            rss = 100.0 if not t[3] else (60.0 if from_nameplate else 99.0)
            out.append((x0, rss, 1000, None, 1, 1.0, None))
        return out


def _ctx(residual):
    data = SimpleNamespace(recs=[SimpleNamespace(residual=residual)])
    base = make_plant("3B")
    return E._Ctx(data=data, runner=_Runner(), base=base, base_dict={"substeps": 20}, nominal=None, progress=None,
                  log=lambda *a: None, skip=lambda *a: None)


def _cur(base):
    spec = Spec(base)
    return F.FitResult(spec, np.full(len(spec.params), 0.5), 100.0, 1000, None, 1)


def test_a_closed_loop_screens_each_candidate_from_the_nameplates_levels_too_and_keeps_the_better_fit():
    ctx = _ctx("observer")
    ref, screened = E._screen(ctx, _cur(ctx.base), ["airflow_torque"], 0)
    assert len(ctx.runner.tasks) == 3            # the current model, the candidate from its levels, from the nameplate's
    (d, cid, fr), = screened
    assert cid == "airflow_torque" and fr.rss == 60.0 and not np.any(fr.x[:len(fr.spec.nominal)])


def test_an_open_loop_screens_from_the_current_models_levels_only():
    ctx = _ctx("replay")
    ref, screened = E._screen(ctx, _cur(ctx.base), ["airflow_torque"], 0)
    assert len(ctx.runner.tasks) == 2 and screened[0][2].rss == 99.0
