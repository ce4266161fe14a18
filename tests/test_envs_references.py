"""Reference signals: values, round trips through to_dict, seeded draws, errors."""
import math
import warnings

import numpy as np
import pytest

from etb_gym.envs.references import (DEFAULT_STEPS_DEG, LIMP_HOME_DEG, REFERENCES, Chirp, Constant, PiecewiseLinear,
                                     Ramp, Sine, Step, Steps, as_reference, fill_steps_table, make_random_task,
                                     make_reference)
from etb_gym.jit import py_func

T = np.arange(3001) * 1e-3


def test_step_constant_ramp_sine_values():
    s = Step(10, 80, 0.05)
    assert s(0.0) == 10.0 and s(0.0499) == 10.0 and s(0.05) == 80.0 and isinstance(s(0.1), float)
    assert np.array_equal(s(np.array([0.0, 0.06])), [10.0, 80.0])
    assert Constant(12.5)(T).tolist() == [12.5] * T.size
    r = Ramp(5, 85, 0.1, 1.0)
    assert r(0.0) == 5.0 and r(0.6) == pytest.approx(45.0) and r(2.0) == 85.0
    assert Sine(40, 30, 1.0)(0.25) == pytest.approx(70.0)


def test_chirp_frequency_sweeps():
    c = Chirp(0.0, 1.0, 1.0, 20.0, 2.0)
    y = c(np.arange(0, 2.0, 1e-4))
    crossings = np.flatnonzero(np.diff(np.signbit(y)))
    early, late = np.diff(crossings[:2]).mean(), np.diff(crossings[-4:]).mean()
    assert late * 1e-4 == pytest.approx(1 / (2 * 20.0), rel=0.05)       # half periods at f1 = 20 Hz at the end
    assert early > 4 * late                                              # ... and much longer at the start


def test_default_steps_cross_limp_home_and_have_large_steps():
    s = Steps()
    v = s(T)
    jumps = np.diff(v)[np.diff(v) != 0]
    assert np.max(np.abs(jumps)) >= 60                                   # large steps
    crossing = [(a, b) for a, b in zip(DEFAULT_STEPS_DEG, DEFAULT_STEPS_DEG[1:])
                if min(a, b) < LIMP_HOME_DEG < max(a, b) and abs(a - b) < 10]
    assert len(crossing) >= 3                                            # small steps across limp-home
    assert s(0.0) == DEFAULT_STEPS_DEG[0] and s(2.99) == DEFAULT_STEPS_DEG[-1]


@pytest.mark.parametrize("name", sorted(REFERENCES))
def test_to_dict_round_trip_and_table(name):
    rng = np.random.default_rng(3)
    params = {"times_s": [0.0, 1.0], "values_deg": [2.0, 40.0]} if name == "piecewise_linear" else {}
    ref = make_reference(name, rng=rng, **params)
    again = as_reference(ref.to_dict())
    assert np.array_equal(again(T), ref(T))
    assert np.array_equal(ref.table(T), ref(T))           # the env's fast episode table equals ref(t)
    assert np.all(np.isfinite(ref(T)))


def test_random_references_are_seeded_and_varied():
    a = make_reference("random_steps", rng=np.random.default_rng(1))
    b = make_reference("random_steps", rng=np.random.default_rng(1))
    c = make_reference("random_steps", rng=np.random.default_rng(2))
    assert a == b and a != c
    v = a(T)
    assert 0.5 <= v.min() and v.max() <= 85.0
    dwell = np.diff(a.times_s)
    assert np.all((dwell >= 0.1 - 1e-12) & (dwell <= 0.4 + 1e-12))
    many = np.concatenate([make_reference("random_steps", rng=np.random.default_rng(s)).values_deg
                           for s in range(20)])
    near = np.abs(many - LIMP_HOME_DEG) <= 4.0
    assert 0.2 < near.mean() < 0.6                       # about 30 % small steps near limp-home (+ chance)


def test_pedal_is_rate_limited_and_spans_idle_to_wide_open():
    values = []
    for s in range(10):
        p = make_reference("pedal", rng=np.random.default_rng(s), duration_s=3.0)
        assert isinstance(p, PiecewiseLinear)
        y = p(T)
        assert np.max(np.abs(np.diff(y))) / 1e-3 <= 400.0 + 1e-6
        assert y[0] == 4.0
        values.append(y)
    y = np.concatenate(values)
    assert y.min() <= 4.0 + 1e-9 and y.max() >= 84.9


@pytest.mark.parametrize("name, params", [("random_steps", {}), ("pedal", {}),
                                          ("random_steps", {"duration_s": 1.0, "min_dwell_s": 0.02,
                                                            "small_step_prob": 0.7, "high_deg": 60.0}),
                                          ("pedal", {"idle_deg": 2.0, "max_deg": 70.0, "min_hold_s": 0.05})])
def test_random_task_draws_what_make_reference_draws_within_its_bounds(name, params):
    """The env validates a random task once (make_random_task) and draws from it at every reset."""
    task = make_random_task(name, **params)
    lo, hi = task.bounds_deg
    for seed in range(30):
        a = task.draw(np.random.default_rng(seed))
        b = make_reference(name, rng=np.random.default_rng(seed), **params)
        assert a == b
        assert lo <= a.values_deg.min() and a.values_deg.max() <= hi
        assert np.array_equal(a.table(T), a(T))


def test_steps_table_kernel_edges():
    for times, values in (([0.0], [7.0]), ([0.5, 1.0], [1.0, 2.0]), ([-1.0, 0.0005, 0.001, 2.9995], [1, 2, 3, 4]),
                          ([0.0, 2.5, 9.0], [1, 2, 3]), ([5.0, 6.0], [1, 2]), ([0.0, 1e-3 * 3000], [1, 2])):
        s = Steps(times, values)
        assert np.array_equal(s.table(T), s(T)), times
        out = np.empty(T.size)
        py_func(fill_steps_table)(s.times_s, s.values_deg, T, out)     # the plain path fills the same table
        assert np.array_equal(out, s(T)), times


@pytest.mark.parametrize("call, match", [
    (lambda: make_reference("stair"), r"unknown reference 'stair'.*'step'"),
    (lambda: make_random_task("steps"), r"not random"),
    (lambda: make_random_task("pedal", hold_s=1), r"unknown parameter.*min_hold_s"),
    (lambda: make_reference("sine", freq=3), r"unknown parameter.*freq.*frequency_hz"),
    (lambda: make_reference("random_steps"), r"rng"),
    (lambda: Step(10, math.nan, 0.1), r"Step.final_deg"),
    (lambda: Steps([0.0, 0.0], [1, 2]), r"increasing"),
    (lambda: Steps([0.0], [1, 2]), r"one time per value"),
    (lambda: Ramp(duration_s=0), r"duration_s"),
    (lambda: make_reference("random_steps", rng=np.random.default_rng(0), min_dwell_s=0.5, max_dwell_s=0.1),
     r"max_dwell_s"),
    (lambda: as_reference({"value_deg": 3}), r"'name'"),
    (lambda: as_reference(3.0), r"expected a name"),
])
def test_bad_references_raise(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_env_variants_pass_gymnasium_checker():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import etb_gym  # noqa: F401

    for kw in (dict(observe_current=True, full_state=True, randomize=True, reference="pedal"),
               dict(reference={"name": "chirp", "f1_hz": 5.0}, sensor={"delay_steps": 3}, pwm_mode="switching")):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            check_env(gym.make("ETB-3B-v0", **kw).unwrapped, skip_render_check=True)
