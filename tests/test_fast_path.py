"""The compiled fast path equals the plain reference path; the batch step equals N single steps; a plant
without compiled kernels falls back visibly (issue 7; the speed harness's report of it: tests/test_speed.py)."""
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.components import LuGreFriction
from etb_gym.components.base import Component, Params
from etb_gym.components.effects_electrical import CoilHeating
from etb_gym.components.effects_friction import AngleDependentFriction, StribeckFriction
from etb_gym.components.effects_mechanical import Backlash
from etb_gym.components.friction import (lugre_damping, lugre_friction_advance, lugre_friction_kernel,
                                         lugre_stribeck)
from etb_gym.integrate import FastPathUnavailableWarning
from etb_gym.jit import HAVE_NUMBA, kernel

ROOT = Path(__file__).resolve().parents[1]
needs_numba = pytest.mark.skipif(not HAVE_NUMBA, reason="the fast path needs numba")


def _effects():
    """The effects of the "3B+effects" plants: state, carried and angle-dependent terms together. One list for
    test_fast_equals_plain and the carry test, so the suite compiles that composition once (cold cache: ~1 min)."""
    return [CoilHeating(), Backlash(play_rad=0.01), StribeckFriction(stiction_Nm=0.05), AngleDependentFriction()]


def _plants():
    return {
        "1A": make_plant("1A"),
        "2B": make_plant("2B"),
        "3B": make_plant("3B"),
        "3C": make_plant("3C"),
        "3B-switching": make_plant("3B", pwm_mode="switching"),
        "2C-switching-9V": make_plant("2C", pwm_mode="switching", supply_V=9.0),
        "3B+effects": make_plant("3B", effects=_effects()),
    }


@needs_numba
@pytest.mark.parametrize("name", list(_plants()))
def test_fast_equals_plain(name, rich_duty):
    p = _plants()[name]
    assert p.fast
    n = 60 if "switching" in name else 200
    d = np.concatenate([rich_duty[300:300 + n // 2], rich_duty[1200:1200 + n // 2]])   # stop + chirp regimes
    a = p.simulate(d, angle_deg=20.0, path="fast")
    b = p.simulate(d, angle_deg=20.0, path="plain")
    np.testing.assert_allclose(a.states, b.states, rtol=1e-10, atol=1e-12)
    for k in a.torques_Nm:
        np.testing.assert_allclose(a.torques_Nm[k], b.torques_Nm[k], rtol=1e-10, atol=1e-12)
    assert np.ptp(a.angle_deg) > 1.0            # the excitation moved the plate: not a trivial comparison


@needs_numba
def test_fast_single_step_equals_plain_engine():
    p = make_plant("3B", pwm_mode="switching")
    x_fast = p.initial_state(math.radians(40.0))
    x_plain = x_fast.copy()
    aux_f, aux_p = np.zeros(4), np.zeros(4)
    for k, d in enumerate((0.9, -0.3, 1e-12, 1.0 - 1e-12, 0.0, -1.0)):   # incl. duties a hair from 0 and 1
        p.engine.fns.control_step(x_fast, d, 12.0, p.P, k * 1e-3, 1e-3, 20, True, 5000.0, aux_f)
        p.engine.plain.control_step(x_plain, d, 12.0, p.P, k * 1e-3, 1e-3, 20, True, 5000.0, aux_p)
        np.testing.assert_allclose(x_fast, x_plain, rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(aux_f, aux_p, rtol=1e-11, atol=1e-13)


def _batch_inputs(p, N, seed=0):
    rng = np.random.default_rng(seed)
    X = np.stack([p.initial_state(math.radians(a)) for a in rng.uniform(0.5, 85.0, N)])
    P = np.stack([p.param_vector({"friction.coulomb_Nm": c, "friction.static_Nm": c * 1.1,
                                  "rotor.inertia_kg_m2": 30e-6 * s})
                  for c, s in zip(rng.uniform(0.1, 0.3, N), rng.uniform(0.9, 1.1, N))])
    V = rng.uniform(9.0, 16.0, N)
    D = rng.uniform(-1.0, 1.0, (25, N))
    return X, P, V, D


@pytest.mark.parametrize("pwm_mode", ["averaged", "switching"])
@pytest.mark.parametrize("parallel", [None, False])
def test_batch_step_equals_single_steps(pwm_mode, parallel):
    p = make_plant("3B", pwm_mode=pwm_mode)
    N = 12
    X, P, V, D = _batch_inputs(p, N)
    Xs = X.copy()
    AUX, auxs = np.zeros((N, 4)), np.zeros((N, 4))
    T = np.zeros(N)
    for k in range(D.shape[0]):
        ok = p.step_batch(X, D[k], V, P, T, AUX, parallel=parallel)
        assert ok.dtype == np.bool_ and ok.all()
        for b in range(N):
            p.step(Xs[b], D[k, b], supply_V=V[b], t0=T[b], aux=auxs[b], P=P[b])
        T += p.control_period_s
    # the same compiled control step, no fastmath: bit for bit
    np.testing.assert_array_equal(X, Xs)
    np.testing.assert_array_equal(AUX, auxs)
    assert np.ptp(X[:, 0]) > 0.1


@needs_numba
def test_batch_step_plain_engine_agrees_and_reports_nonfinite():
    """(3B, whose parallel batch step test_batch_step_equals_single_steps compiles already: on 3A this test alone
    compiled a batch step, ~13 s CPU on a cold cache.)"""
    p = make_plant("3B")
    N = 4
    X, P, V, D = _batch_inputs(p, N, seed=1)
    Xp, AUX, AUXp, OK, OKp = X.copy(), np.zeros((N, 4)), np.zeros((N, 4)), np.zeros(N, bool), np.zeros(N, bool)
    args = (D[0], V, P, np.zeros(N), 1e-3, 20, False, 5000.0)
    p.engine.fns.batch_step(X, *args, AUX, OK)
    p.engine.plain.batch_step(Xp, *args, AUXp, OKp)
    np.testing.assert_allclose(X, Xp, rtol=1e-11, atol=1e-13)
    assert OK.all() and OKp.all()
    X[2, 1] = np.nan                                   # a broken row is flagged, the others still step
    ok = p.step_batch(X, D[1], V, P, np.zeros(N), AUX)
    assert ok.tolist() == [True, True, False, True]


def test_step_batch_does_not_leak_or_alias():
    """The batch step borrows its arrays without reference counts: inputs stay valid and unaliased."""
    p = make_plant("3B")
    X, P, V, D = _batch_inputs(p, 6)
    P0 = P.copy()
    refs = [sys.getrefcount(a) for a in (X, P, V)]
    for k in range(5):
        p.step_batch(X, D[k], V, P, np.zeros(6), np.zeros((6, 4)))
    assert [sys.getrefcount(a) for a in (X, P, V)] == refs
    np.testing.assert_array_equal(P, P0)               # parameters are read only
    assert np.all(np.isfinite(X))


# ---------------------------------------------------------------------------------------------- carried values
@kernel
def _lugre_kernel_recomputing(t, phi, omega, i, u, s, p, ds):
    return lugre_friction_kernel(t, phi, omega, i, u, s, p, ds, lugre_stribeck(phi, omega, i, p))


@kernel
def _lugre_advance_recomputing(h, t, phi, omega, i, u, s, p):
    lugre_friction_advance(h, t, phi, omega, i, u, s, p, lugre_stribeck(phi, omega, i, p))


@kernel
def _lugre_damping_recomputing(phi, omega, i, s, p):
    return lugre_damping(phi, omega, i, s, p, lugre_stribeck(phi, omega, i, p))


class _LuGreRecomputing(LuGreFriction):
    """LuGre without a carry: kernel and advance each evaluate g(omega) themselves (the naive path)."""

    kind = ""                      # not registered
    kernel = staticmethod(_lugre_kernel_recomputing)
    advance = staticmethod(_lugre_advance_recomputing)
    damping = staticmethod(_lugre_damping_recomputing)
    carry = None


def _carry_cases():
    """Each case compiles a recomputing twin no other test needs (~10 s CPU on a cold cache), so two cases that
    between them take every generated path: switching PWM (control_step_dx, single and batch) on the linear drive,
    averaged PWM (control_step_group) on the nonlinear-inductance drive with four effects beside the carry (a state
    effect, a second friction term and the backlash's contacts, whose resolve path carries the value too)."""
    return {"3A-switching": make_plant("3A", pwm_mode="switching"),
            "3B+effects": make_plant("3B", effects=_effects())}


@pytest.mark.parametrize("name", list(_carry_cases()))
def test_carried_stribeck_curve_gives_the_same_bits_as_recomputing_it(name, rich_duty):
    """LuGre's g(omega) is computed once per substep and carried to the next substep's kernel
    (integrate.py, "Carried values"): the trajectories equal, bit for bit, those of a LuGre that evaluates
    g in its kernel and again in its advance, on the fast and the plain path, single and batch steps.

    The batch steps run serially: batch_step_serial calls the same control_step_group (averaged PWM) and
    control_step_dx (switching) per plant as the parallel batch_step runs on each thread, so the carried values
    are checked on every generated path; that the parallel batch step equals single steps is
    test_batch_step_equals_single_steps. (Checking parallel=None here too compiled a parallel batch step for
    compositions no other test steps in parallel: the recomputing ones and 3B+effects.) The carrying plant's batch
    steps are compared with the recomputing twin's single control steps (Plant.step): a batch step of the twin
    compiled its own batch_step_serial and control_step_group, 8.6 s (3A) and 15.8 s (3B+effects) of compile CPU
    on a cold cache, where the twin's control_step is a small call of the control_step_dx it compiled already."""
    p = _carry_cases()[name]
    q = p.replace(friction=_LuGreRecomputing(p.friction.params))
    assert "c1n = substep(" in p.engine.source and "c1" not in q.engine.source
    assert p.fast == q.fast == HAVE_NUMBA
    sw = "switching" in name
    d = rich_duty[:2000:4 if sw else 1]
    paths = ("fast", "plain") if HAVE_NUMBA else ("plain",)
    for path in paths:
        dd = d if path == paths[0] else np.concatenate([d[100:140], d[-40:]])
        a, b = p.simulate(dd, angle_deg=20.0, path=path), q.simulate(dd, angle_deg=20.0, path=path)
        np.testing.assert_array_equal(a.states, b.states)
        for k in a.torques_Nm:
            np.testing.assert_array_equal(a.torques_Nm[k], b.torques_Nm[k])
        if path == paths[0]:       # not a trivial comparison: the plate swept the range, the bristle moved
            assert np.ptp(a.angle_deg) > 10.0 and np.ptp(a.state("friction.z_rad")) > 0.0
    X, P, V, D = _batch_inputs(p, 7)
    D[3, 0], D[4, 1] = 1e-12, 1.0 - 1e-12
    Xp, Xq, Ap, Aq = X.copy(), X.copy(), np.zeros((7, len(p.components))), np.zeros((7, len(p.components)))
    for k in range(D.shape[0]):
        assert p.step_batch(Xp, D[k], V, P, np.full(7, k * 1e-3), Ap, parallel=False).all()
        for b in range(7):
            q.step(Xq[b], D[k, b], supply_V=V[b], t0=k * 1e-3, aux=Aq[b], P=P[b])
    np.testing.assert_array_equal(Xp, Xq)
    np.testing.assert_array_equal(Ap, Aq)
    ref_p, ref_q = p.reference(d[:5], angle_deg=20.0), q.reference(d[:5], angle_deg=20.0)   # rhs from the state
    np.testing.assert_array_equal(ref_p.states, ref_q.states)


# ---------------------------------------------------------------------------------------------- plain fallback
@dataclasses.dataclass(frozen=True)
class _PlainTorqueParams(Params):
    torque_Nm: float = 0.01


def _plain_torque_kernel(t, phi, omega, i, u, s, p, ds):
    return p[0], 0.0, 0.0


class _PlainTorque(Component):
    """A component whose kernel is not compiled (as a user's first draft of a new effect would be)."""

    Params = _PlainTorqueParams
    kernel = staticmethod(_plain_torque_kernel)


@needs_numba
def test_plain_fallback_is_visible_and_still_correct():
    with pytest.warns(FastPathUnavailableWarning, match="_PlainTorque"):
        p = make_plant("3B", effects=[_PlainTorque()])
    assert p.fast is False and make_plant("3B").fast is True
    X, P, V, D = _batch_inputs(p, 3)
    Xs = X.copy()
    p.step_batch(X, D[0], V, P, np.zeros(3), np.zeros((3, 5)))
    for b in range(3):
        p.step(Xs[b], D[0, b], supply_V=V[b], P=P[b])
    np.testing.assert_array_equal(X, Xs)


@needs_numba
@pytest.mark.parametrize("env, expected", [
    ({}, "OMP_WAIT_POLICY=PASSIVE"),
    ({"OMP_WAIT_POLICY": "ACTIVE"}, "user setting kept"),
    ({"NUMBA_THREADING_LAYER": "workqueue"}, "user setting kept"),
])
def test_thread_pool_sleeps_unless_the_user_chose(env, expected):
    import os
    import subprocess

    clean = {k: v for k, v in os.environ.items()
             if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "NUMBA_THREADING_LAYER")}
    code = ("import os, etb_gym.integrate as I; "
            "assert I.THREAD_POOL is None; print(I.ensure_thread_pool() + '|' + os.environ.get('OMP_WAIT_POLICY', '-'))")
    out = subprocess.run([sys.executable, "-c", code], env={**clean, **env}, capture_output=True, text=True,
                         timeout=120, check=True).stdout.strip().splitlines()[-1]
    pool, policy = out.split("|")
    assert pool == expected
    assert policy == env.get("OMP_WAIT_POLICY", "PASSIVE" if not env else "-")


@needs_numba
def test_substep_loop_makes_no_reference_count_calls():
    """The lockstep group, the careful contact path and the plausibility check borrow their arrays themselves:
    a kernel's slice of a borrowed view then needs no NRT_incref/NRT_decref call (a real call that spills every
    live register; without the borrows 1A's control_step_group held 44 of them and ran 1.4-1.6x slower,
    docs/speed.md "Round 4"). Compiled in memory (the cached build cannot show its LLVM IR)."""
    import re

    import numba

    from etb_gym import integrate
    from etb_gym.kernel_cache import borrow

    p = make_plant("1A")
    ns = dict(p.engine.bound, prange=numba.prange, borrow=borrow)
    exec(compile(p.engine.source, "<test stepper>", "exec"), ns)
    for name, opts in integrate.JIT_OPTIONS.items():
        ns[name] = numba.njit(**opts)(ns[name])
    N = 4
    X, P = np.tile(p.initial_state(), (N, 1)), np.tile(p.P, (N, 1))
    AUX, ok = np.zeros((N, len(p.components))), np.empty(N, np.bool_)
    ns["batch_step_serial"](X, np.full(N, 0.9), np.full(N, 12.0), P, np.zeros(N), 1e-3, 20, False, 5000.0, AUX, ok)
    assert ok.all()
    counts = {}
    for fn in ("control_step_group", "resolve", "physical", "control_step_dx"):
        for ll in ns[fn].inspect_llvm().values():
            for m in re.finditer(r"^define [^@]*@(\S+?)\(.*?^}", ll, re.S | re.M):
                if "cpython" in m.group(1) or m.group(1).startswith("cfunc") or "NRT_" in m.group(1):
                    continue
                short = re.sub(r"^_ZN13_3cdynamic_3e\d+", "", m.group(1)).split("B")[0]
                counts[short] = len(re.findall(r"call void @NRT_(?:in|de)cref", m.group(0)))
    assert {"control_step_group", "resolve", "physical", "control_step_dx"} <= set(counts), counts
    assert not any(counts.values()), f"reference-count calls in the stepper: {counts}"


@needs_numba
def test_rhs_is_compiled_once_for_the_plant_and_the_envs():
    """Plant.initial_state, Plant.reference and the envs' resets (randomized or not) call the generated rhs with a read-only P
    (plant.read_only): a writable P from the plant beside the envs' read-only one compiled rhs twice per
    composition (numba compiles once per argument type)."""
    import gymnasium as gym

    p = make_plant("3B")
    p.reference(np.full(2, 0.2))
    gym.make("ETB-3B-v0").reset(seed=0)
    gym.make("ETB-3B-v0", randomize=True).reset(seed=0)       # a drawn P, made read-only too
    gym.make_vec("ETB-3B-v0", num_envs=2).reset(seed=0)
    sigs = p.engine.fns.rhs.signatures
    assert len(sigs) == 1 and not sigs[0][3].mutable, sigs
