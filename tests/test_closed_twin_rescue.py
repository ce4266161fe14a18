"""closed_twin.replay_rescue: a closed loop's table that the observer's folds keep below family_table.MIN_GAIN, kept
when the replay of the recorded voltage (which neither model was fitted on) gains clearly and the observer's cost
does not rise (round 28). Stand-ins for the two residuals: no simulation."""
import types

import numpy as np

from etb_gym.diagnose import closed_twin as CT

N = 6000


def _case(monkeypatch, replay=(11387.0, 5546.0), observer=(5866.0, 5757.0), heldout=(0.977, 0.942),
          residual="observer"):
    cur = types.SimpleNamespace(spec="formula", x=np.zeros(3))
    ref = types.SimpleNamespace(fit=types.SimpleNamespace(spec="table", x=np.zeros(5)), kept=False,
                                heldout_formula=heldout[0], heldout_map=heldout[1],
                                term=types.SimpleNamespace(id="torque_constant_error_torque_offset"))
    data = types.SimpleNamespace(recs=[types.SimpleNamespace(residual=residual)], continuity=True)
    costs = {"formula": (replay[0], observer[0]), "table": (replay[1], observer[1])}
    replay = types.SimpleNamespace(continuity=True)             # the replay view; ``data`` is the observer's
    monkeypatch.setattr(CT, "replay_view", lambda d: replay)
    monkeypatch.setattr(CT, "_replay_cost", lambda fr, rv: (costs[fr.spec][0 if rv is replay else 1], N))
    return cur, ref, data


def test_a_table_the_folds_hardly_see_is_kept_where_the_replay_halves_its_cost(monkeypatch):
    assert CT.replay_rescue(*_case(monkeypatch), log=lambda *a: None)


def test_a_small_replay_gain_does_not_keep_it(monkeypatch):
    assert not CT.replay_rescue(*_case(monkeypatch, replay=(11387.0, 10000.0)), log=lambda *a: None)


def test_the_observer_may_not_lose_more_than_its_noise(monkeypatch):
    assert not CT.replay_rescue(*_case(monkeypatch, observer=(5866.0, 6100.0)), log=lambda *a: None)


def test_folds_that_lose_or_an_open_loop_do_not_take_the_path(monkeypatch):
    assert not CT.replay_rescue(*_case(monkeypatch, heldout=(0.977, 0.99)), log=lambda *a: None)
    assert not CT.replay_rescue(*_case(monkeypatch, residual="replay"), log=lambda *a: None)


def test_a_kept_table_or_none_is_left_alone(monkeypatch):
    cur, ref, data = _case(monkeypatch)
    ref.kept = True
    assert not CT.replay_rescue(cur, ref, data, log=lambda *a: None)
    assert not CT.replay_rescue(cur, None, data, log=lambda *a: None)
