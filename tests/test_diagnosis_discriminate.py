"""Confusable angle-dependent torques (diagnose.discriminate): the family is named by what the torque
multiplies (the current, the direction of motion, nothing), with each family's shape left free."""
import math

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.components import effects as fx
from etb_gym.diagnose import discriminate as D
from etb_gym.diagnose import fit as F
from etb_gym.diagnose.model import Spec, prepare
from etb_gym.diagnose.synthetic import make_recording

PHI = np.radians(np.linspace(0.0, 90.0, 31))


def _friction_bump():
    """Extra friction in a Gaussian band around 40 deg (the candidate's is linear + quadratic in phi)."""
    lvl = 0.08 * np.exp(-0.5 * ((PHI - math.radians(40.0)) / math.radians(10.0)) ** 2)
    return fx.AngleFrictionMap(angle_rad=tuple(PHI), level_Nm=tuple(lvl), presliding_rad=1e-3)


def _flux_step():
    """Torque constant falling in a logistic step at 50 deg (the candidate's is a power of phi)."""
    dk = -0.012 / (1.0 + np.exp(-(PHI - math.radians(50.0)) / math.radians(6.0)))
    return fx.TorqueConstantMap(angle_rad=tuple(PHI), delta_Nm_per_A=tuple(dk))


@pytest.mark.parametrize("truth, leader, right", [
    (_friction_bump, "airflow_torque", "angle_dependent_friction"),
    (_flux_step, "airflow_torque", "shaft_flux_loss"),
])
def test_the_right_family_is_named_over_its_neighbour(truth, leader, right):
    truth_plant = make_plant("3B", substeps=40, effects=[truth()])
    rec = make_recording(truth_plant, np.random.default_rng(3), duration_s=3.0, name="rig.csv")
    data = prepare([rec], 12.0)
    nominal = F.fit(Spec(make_plant("3B", substeps=20)), data, max_nfev=40)
    ev = D.discriminate(nominal, data, [leader, right], log=lambda *a: None)
    assert ev["winner"] == right, ev
    assert ev["rivals"] == [leader]
    assert ev["heldout_table"][right] < 0.5 * ev["heldout_table"][leader], ev["heldout_table"]


class _Fit:
    def __init__(self, rss):
        self.rss = rss


def test_rivals_are_group_members_close_to_the_leader_with_another_table():
    screened = [(-900, "airflow_torque", _Fit(40.0)), (-800, "angle_dependent_friction", _Fit(55.0)),
                (-700, "spring_asymmetry", _Fit(60.0)), (-600, "coil_heating", _Fit(45.0)),
                (-100, "shaft_flux_loss", _Fit(90.0))]
    # drops below 100: airflow 60, friction 45 (>= 30), spring 40, flux 10 (< 30); coil heating not in the group
    assert D.rivals(screened, 100.0, "airflow_torque") == ["airflow_torque", "angle_dependent_friction",
                                                           "spring_asymmetry"]
    assert D.rivals(screened, 100.0, "coil_heating") == []
    # airflow and spring share the angle-only table: nothing to tell apart by physics
    assert D.rivals(screened[:1] + screened[2:3], 100.0, "airflow_torque") == []
