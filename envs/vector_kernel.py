"""The native vector env's compiled step: plants, rewards, sensing, observations and info in one parallel call.

:func:`vector_step_for` returns, for a plant's composition, ``vector_step(...)``: one ``prange`` over the sub-envs
(in the stepper's lockstep groups of ``integrate.GROUP`` plants with averaged PWM) that steps each group's plants
(the composition's ``control_step_group`` / ``control_step_dx``, the batch step's own calls, so the same bits) and
then, per live sub-env, counts the step, computes the reward and truncation (:func:`~etb_gym.envs.kernel.step_reward`)
and its reading, observation and info column (:func:`observe_row`, which draws the next noise block in place when
the current one is used up: :func:`~etb_gym.envs.noise.fill_normals`). Sub-envs about to be reset (``ignored``) are
stepped (harmlessly, at duty 0) but not observed: the caller resets them. Nothing is allocated per step in it.

The function is composition-dependent (it calls the composition's stepper), so it is generated: a small module
``etb_vector_<digest>.py`` written next to the stepper's module in the kernel cache (``ETB_GYM_CACHE``) that imports
the stepper's functions by name, compiled with ``cache=True`` (numba cannot cache a function that takes the stepper
as an argument: measured, it compiles anew in every process). It holds two entry points, ``vector_step`` (parallel)
and ``vector_step_serial`` (the same loop on the calling thread, for one thread), each compiled on the first step
that needs it (3B at load 11: 9 and 3 s of CPU). Where the stepper is not in the kernel cache (kernels numba cannot cache from) it is
compiled in memory; on the plain path it is the same source run by CPython.
"""
from __future__ import annotations

import hashlib
import inspect
import sys

from etb_gym.components import effects_maps, sensor

from etb_gym.components.sensor import delay_push, sense, shape_reading
from etb_gym.integrate import GROUP
from etb_gym.jit import HAVE_NUMBA, kernel, py_func
from etb_gym.kernel_cache import borrow, identity

from . import kernel as kernel_mod
from . import noise, observation
from .kernel import NOISE_BLOCK, RAD2DEG, step_reward
from .noise import fill_normals
from .observation import encode_current_into, encode_into, encode_supply_into


def _inlined_kernel(fn):
    """A kernel that numba inlines into its callers (as the stepper's rhs): a call per sub-env with two dozen array
    arguments, each passed as its seven fields, cost more than the row's work (measured: 300 vs 30 ns)."""
    if HAVE_NUMBA:
        import numba

        return numba.njit(inline="always", cache=True, error_model="numpy")(fn)
    return kernel(fn)


@_inlined_kernel
def observe_row(b, j, X, AUX, last_duty, supply_V, K, dt, ref_table, max_steps, delay_buf, delay_pos, shape,
                shape_line, shape_pos, noise, noise_pos, noise_std, noise_words, sensor, observe_current,
                observe_supply, state_scale, clip, obs_low, obs_high, info_cols, obs, info):
    """Sub-env ``b``'s reading, observation (written to ``obs[j]``) and info (column ``j`` of ``info``, keys in the
    order INFO_KEYS, torques, t_s): the single env's ``_observe``. ``sensor`` = (gain, offset, resolution, current
    noise std, current resolution, supply noise std, supply resolution); ``shape``, ``shape_line``, ``shape_pos``:
    a plant file's reading maps after the delay line (components.sensor.shape_reading); ``state_scale`` is empty unless the full
    state is observed; ``info_cols``: the AUX column of each torque key (-1: no such component, 0). A used-up noise
    block is refilled from the sub-env's PCG64 words first, as the single env draws its next block."""
    phi, omega, cur = X[b, 0], X[b, 1], X[b, 2]
    phi_read, delay_pos[b] = delay_push(delay_buf[b], delay_pos[b], phi)
    phi_read, shape_pos[b] = shape_reading(phi_read, shape_line[b], shape_pos[b], shape)
    pos = noise_pos[b]
    if pos == NOISE_BLOCK:
        fill_normals(noise[b], noise_words[b])
        pos = 0
    noise_pos[b] = pos + 1
    s_deg = sense(phi_read, sensor[0], sensor[1], noise_std[b] * noise[b, pos, 0], sensor[2]) * RAD2DEG
    k = K[b]
    r = ref_table[b, min(k, max_steps)]
    d = last_duty[b]
    V = supply_V[b]
    o = obs[j]
    encode_into(o, s_deg, r, d)
    if observe_current:
        encode_current_into(o, sense(cur, 1.0, 0.0, sensor[3] * noise[b, pos, 1], sensor[4]))
    if observe_supply:
        encode_supply_into(o, 5 if observe_current else 4, sense(V, 1.0, 0.0, sensor[5] * noise[b, pos, 2], sensor[6]))
    n_obs = o.shape[0]
    n_x = state_scale.shape[0]
    for m in range(n_x):
        o[n_obs - n_x + m] = X[b, m] * state_scale[m]
    if clip:
        for m in range(n_obs):
            o[m] = max(min(o[m], obs_high[m]), obs_low[m])
    info[0, j] = phi * RAD2DEG
    info[1, j] = s_deg
    info[2, j] = omega * RAD2DEG
    info[3, j] = cur
    info[4, j] = d * V
    info[5, j] = d
    info[6, j] = r
    info[7, j] = V
    for c in range(info_cols.shape[0]):
        col = info_cols[c]
        info[8 + c, j] = AUX[b, col] if col >= 0 else 0.0
    info[info.shape[0] - 1, j] = k * dt


@kernel
def observe_rows(rows, X, AUX, last_duty, supply_V, K, dt, ref_table, max_steps, delay_buf, delay_pos, shape,
                 shape_line, shape_pos, noise, noise_pos, noise_std, noise_words, sensor, observe_current,
                 observe_supply, state_scale, clip, obs_low, obs_high, info_cols, obs, info):
    """:func:`observe_row` for sub-envs ``rows`` (the resets): row ``b = rows[j]`` to ``obs[j]``, ``info[:, j]``.
    The arrays are borrowed first, as in vector_step (4x faster)."""
    X, AUX, last_duty, supply_V, K, ref_table = borrow(X), borrow(AUX), borrow(last_duty), borrow(supply_V), \
        borrow(K), borrow(ref_table)
    delay_buf, delay_pos, noise, noise_pos = borrow(delay_buf), borrow(delay_pos), borrow(noise), borrow(noise_pos)
    shape, shape_line, shape_pos = borrow(shape), borrow(shape_line), borrow(shape_pos)
    noise_std, noise_words, sensor, state_scale = borrow(noise_std), borrow(noise_words), borrow(sensor), \
        borrow(state_scale)
    obs_low, obs_high, info_cols, obs, info = borrow(obs_low), borrow(obs_high), borrow(info_cols), borrow(obs), \
        borrow(info)
    for j in range(rows.shape[0]):
        observe_row(rows[j], j, X, AUX, last_duty, supply_V, K, dt, ref_table, max_steps, delay_buf, delay_pos,
                    shape, shape_line, shape_pos, noise, noise_pos, noise_std, noise_words, sensor, observe_current,
                    observe_supply, state_scale, clip, obs_low, obs_high, info_cols, obs, info)


# The generated step. group_step / one_step are the composition's control_step_group / control_step_dx.
TEMPLATE = '''
def vector_step(duty, ignored, X, P, V, K, AUX, T0, DX, OK, last_duty, dt, n_sub, switching, f_pwm,
                ref_table, max_steps, weights, delay_buf, delay_pos, shape, shape_line, shape_pos,
                noise, noise_pos, noise_std, noise_words, sensor,
                observe_current, observe_supply, state_scale, clip, obs_low, obs_high, info_cols, reward, truncated,
                obs, info):
    """One step of every sub-env (see etb_gym.envs.vector_kernel). Rows with ``ignored`` set are stepped but not
    counted or observed (the caller resets them)."""
    n = X.shape[0]
    # views without reference counts (kernel_cache.borrow): numba counts every array variable the inlined observe_row
    # binds and every row slice, atomically, on the array's one count, a cache line both threads write
    Xb, Pb, Ab, DXb = borrow(X), borrow(P, True), borrow(AUX), borrow(DX)
    duty, ignored, V, K, T0, OK, last_duty = borrow(duty), borrow(ignored), borrow(V), borrow(K), borrow(T0), \
        borrow(OK), borrow(last_duty)
    ref_table, weights, delay_buf, delay_pos = borrow(ref_table), borrow(weights), borrow(delay_buf), borrow(delay_pos)
    shape, shape_line, shape_pos = borrow(shape), borrow(shape_line), borrow(shape_pos)
    noise, noise_pos, noise_std, noise_words = borrow(noise), borrow(noise_pos), borrow(noise_std), borrow(noise_words)
    sensor, state_scale, obs_low, obs_high = borrow(sensor), borrow(state_scale), borrow(obs_low), borrow(obs_high)
    info_cols, reward, truncated, obs, info = borrow(info_cols), borrow(reward), borrow(truncated), borrow(obs), \
        borrow(info)
    G = 1 if switching else GROUP
    for j in prange((n + G - 1) // G):
        b0 = j * G
        b1 = min(b0 + G, n)
        if b1 - b0 == GROUP and not switching:
            for b in range(b0, b1):
                T0[b] = K[b] * dt
            group_step(Xb, duty, V, Pb, T0, Ab, DXb, OK, b0, dt, n_sub)
        else:
            for b in range(b0, b1):
                OK[b] = one_step(Xb[b], duty[b], V[b], Pb[b], K[b] * dt, dt, n_sub, switching, f_pwm, Ab[b], DXb[b])
        for b in range(b0, b1):
            if ignored[b]:
                continue
            k = K[b] + 1
            K[b] = k
            r = ref_table[b, min(k, max_steps)]
            reward[b] = step_reward(r - X[b, 0] * RAD2DEG, duty[b], last_duty[b], weights[0], weights[1], weights[2])
            last_duty[b] = duty[b]
            truncated[b] = k >= max_steps
            observe_row(b, b, Xb, Ab, last_duty, V, K, dt, ref_table, max_steps, delay_buf, delay_pos, shape,
                        shape_line, shape_pos, noise, noise_pos, noise_std, noise_words, sensor, observe_current,
                        observe_supply, state_scale, clip, obs_low, obs_high, info_cols, obs, info)
'''
_HEADER = '''# generated by etb_gym.envs.vector_kernel for the stepper module {stepper}
import numpy as np
from numba import njit, prange
from {stepper} import control_step_group as group_step, control_step_dx as one_step
from etb_gym.envs.kernel import RAD2DEG, step_reward
from etb_gym.envs.vector_kernel import GROUP, observe_row
from etb_gym.kernel_cache import borrow
'''

_built: dict = {}      # (stepper namespace id, parallel) -> vector_step


def serial_source() -> str:
    """TEMPLATE as ``vector_step_serial``: the same loop on the calling thread (no thread-pool launch, ~2 us)."""
    return TEMPLATE.replace("def vector_step(", "def vector_step_serial(").replace("prange(", "range(")


def vector_step_for(plant, parallel: bool):
    """The compiled (or, on the plain path, plain) ``vector_step`` of ``plant``'s composition, in parallel over the
    sub-envs or on the calling thread (each built once, compiled on its first call)."""
    fn = py_func(plant.stepper("fast").batch_step)
    key = (id(fn.__globals__), bool(parallel))
    if key not in _built:
        _built[key] = _build(fn.__globals__, fn.__module__, bool(plant.fast), bool(parallel))
    return _built[key]


def _build(stepper_ns: dict, stepper_module, fast: bool, parallel: bool):
    if fast and stepper_module in sys.modules and str(stepper_module).startswith("etb_gym_kernels."):
        try:
            mod = _load_cached(stepper_module)
            return mod.vector_step if parallel else mod.vector_step_serial
        except OSError:
            pass
    ns = {"group_step": stepper_ns["control_step_group"], "one_step": stepper_ns["control_step_dx"],
          "GROUP": GROUP, "RAD2DEG": RAD2DEG, "step_reward": step_reward, "observe_row": observe_row}
    if fast:                  # stepper compiled in memory (kernels numba cannot cache from): so is this
        import numba

        ns.update(prange=numba.prange, borrow=borrow)
        exec(compile(TEMPLATE if parallel else serial_source(), "<etb_gym vector step>", "exec"), ns)
        return numba.njit(parallel=parallel)(ns["vector_step" if parallel else "vector_step_serial"])
    ns.update(prange=range, borrow=identity, step_reward=py_func(step_reward), observe_row=py_func(observe_row))
    exec(compile(TEMPLATE, "<etb_gym plain vector step>", "exec"), ns)
    return ns["vector_step"]


def _load_cached(stepper_module: str):
    """Write the generated module into the kernel cache (once per stepper module) and import it."""
    import numba

    from etb_gym.kernel_cache import import_cached_source

    src = (_HEADER.format(stepper=stepper_module) + "\n@njit(parallel=True, cache=True)" + TEMPLATE
           + "\n@njit(cache=True)" + serial_source())
    # numba's cache does not see a change in a callee's module: the digest covers their sources
    deps = "".join(inspect.getsource(m) for m in (sys.modules[__name__], kernel_mod, noise, observation, sensor,
                                                  effects_maps))
    digest = hashlib.sha256((src + deps + numba.__version__).encode()).hexdigest()[:20]
    return import_cached_source(src, "etb_vector", "v", digest, ("vector_step", "vector_step_serial"))
