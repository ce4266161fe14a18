"""What the diagnosis does to save time must not change what it finds (docs/diagnosis-shapes.md, Time):
Spec.build's remembered nominal plants and the table Jacobian's reused residual are exact."""
import numpy as np

from etb_gym import make_plant
from etb_gym.diagnose import shapes as S
from etb_gym.diagnose import penalized as P
from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.model import Spec, prepare
from etb_gym.diagnose.shapes_eval import AngleShape
from etb_gym.diagnose.synthetic import make_recording


def test_spec_build_remembers_nominal_plants_without_mixing_them_up():
    """Builds in any order (knot values only, nominal values, back again, more distinct nominal values than
    remembered) give exactly the plants of a Spec that remembers nothing."""
    base = make_plant("3B", substeps=20)
    spec = Spec(base).with_candidate(CANDIDATES["airflow_torque"])
    n_nom = len(spec.nominal)
    rng = np.random.default_rng(0)
    xs = []
    for k in range(12):
        x = np.zeros(len(spec.params))
        if k % 3:                                   # a nominal parameter moved (one of 6 distinct sets)
            x[:n_nom] = 0.1 * rng.integers(-3, 3, n_nom)
        x[n_nom:] = rng.normal(0.0, 0.5, len(x) - n_nom)
        xs.append(x)
    xs += xs[::-1]
    for x in xs:
        p, s = spec.build(x)
        q, t = Spec(base, spec.candidates, spec.nominal).build(x)
        np.testing.assert_array_equal(p.P, q.P)
        assert p.params_dict() == q.params_dict() and s == t


def _problem():
    """A 2 s open-loop recording of 3B with a Gaussian airflow bump; 3B + airflow_torque + its table (the
    composition tests/test_diagnosis_shapes.py compiles)."""
    bump = AngleShape(peak_Nm=-0.06, centre_rad=np.radians(45.0), width_rad=np.radians(12.0))
    rec = make_recording(make_plant("3B", substeps=40, effects=[bump]), np.random.default_rng(7), duration_s=2.0,
                         name="bump.csv")
    data = prepare([rec], 12.0)
    spec = Spec(make_plant("3B", substeps=20)).with_candidate(CANDIDATES["airflow_torque"])
    term = S.family_term("airflow_torque", spec.base, data)
    spec_m = spec.with_candidate(term.candidate())
    pb = P.Problem.make(spec_m, np.zeros(len(spec_m.params)), ("nominal", term.id), [term], data)
    return pb, data


def test_table_jacobian_reuses_the_residual_at_the_models_own_step():
    pb, data = _problem()
    r = P._residual(pb.spec, data, pb.x)
    np.testing.assert_array_equal(P._jacobian_at(pb, data, r, P.JAC_SUBSTEPS), P.jacobian(pb, data, r.copy()))
