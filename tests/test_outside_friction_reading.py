"""Round 32 (i32outside): the open-loop friction reading of an outside description whose period is not established
(unmodelled.catalogue_alternative, g30adf) does not name a friction family that predicts the held-out folds an
order worse than the description, where the description leaves only the noise (detent_torque random open s42: an
18.07 deg series, held-out 1.41; angle_dependent_friction with its table 156, named, twin 63x)."""
import pytest
from diagnose_stubs import Alt, Cur
from diagnose_stubs import generic as stub_generic

from etb_gym.diagnose import unmodelled as U


@pytest.mark.parametrize("h_family, h_description, outdone", [
    (156.0, 1.41, True),     # detent_torque random open s42: the series at the noise, the friction 110 times worse
    (146.0, 12.8, False),    # angle_dependent_friction@1 random open s38: the series short of the noise
    (30.7, 7.82, False),     # ... s36 (and s40: 23 against 16.4)
    (5.0, 1.0, False),       # at the noise both, within an order
    (40.0, 4.0, False),      # an order worse exactly: not outdone
    (40.1, 4.0, True),
    (float("nan"), 1.0, True),
    (1e3, float("nan"), False),
])
def test_a_family_an_order_worse_than_a_description_at_the_noise_is_outdone(h_family, h_description, outdone):
    assert U.outdone_by_description(h_family, h_description) is outdone


@pytest.mark.parametrize("h_family, h_description, expect", [
    (156.0, 1.41, None),                           # outside the catalogue stays (the detent)
    (146.0, 12.8, "angle_dependent_friction"),     # the friction reading as before (adf@1 random open s38)
    (5.0, 1.41, "angle_dependent_friction"),       # within an order of a description at the noise
])
def test_the_friction_reading_yields_to_a_description_that_leaves_the_noise(monkeypatch, h_family, h_description,
                                                                            expect):
    def fake_try(cur, cid, data, log):
        return U.FamilyAlternative(cid, Alt(), None, h_family, h_family)

    logged = []
    monkeypatch.setattr(U, "_try_family", fake_try)
    monkeypatch.setattr(U, "_rms_deg", lambda spec, x, data: 1.0 if x is Cur.x else 0.5)
    monkeypatch.setattr(U, "period_established", lambda g, ps, data, log=None: False)
    monkeypatch.setattr(U, "open_loop", lambda data: True)
    alt = U.catalogue_alternative(stub_generic(["unmodelled_current", "unmodelled_angle"], h_description, True), Cur(),
                                  {"unmodelled_angle": ("airflow_torque", "angle_dependent_friction")}, None,
                                  lambda fr: True, log=logged.append, h_catalogue=None)
    assert (alt.id if alt else None) == expect
    assert any("an order worse" in m for m in logged) == (expect is None)
