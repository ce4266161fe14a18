"""A native batched vector env: N throttle plants stepped together in one compiled, parallel call.

    envs = gym.make_vec("ETB-3B-v0", num_envs=1024)            # this class (the id's vector entry point)
    obs, info = envs.reset(seed=0)                               # sub-env k seeded with 0 + k
    obs, rew, term, trunc, info = envs.step(envs.action_space.sample())

It is the same MDP as N :class:`~etb_gym.envs.env.ETBEnv` in a ``SyncVectorEnv``, step for step and bit for
bit (tests/test_envs_vector.py): sub-env k owns a generator seeded like ``SyncVectorEnv`` seeds it
(``seed + k``), draws its episodes with the single env's :meth:`ETBEnv.draw_episode`, and reads its
sensor from noise blocks drawn in the same order. The plants advance together through
``Plant.step_batch``; reward, sensing, observation and info of all sub-envs are then one compiled loop
(:func:`step_rewards`, :func:`observe_rows`) that calls the single env's kernels (``step_reward``,
``sense``, ``delay_push``, ``observation.encode_into``) per sub-env. All it takes from the single env is its
public :class:`~etb_gym.envs.kernel.EnvKernel` (``env.kernel``: stepper, constants, observation layout) and
its episode draws (tests/test_envs_vector.py checks that this module reads no private attribute of it).
Autoreset is Gymnasium's default ``NEXT_STEP`` mode: the step after a sub-env is truncated resets it
(its action is ignored, reward 0) and returns the reset observation and info. ``info`` is a dict of arrays
with ``_key`` masks, as ``SyncVectorEnv`` builds it. Rendering is not supported here (use
``vectorization_mode="sync"`` to render sub-envs).

``num_threads`` (keyword) sets the threads of the parallel batch step. Default: 1 below 64 sub-envs
(waking a thread pool costs more than stepping a few dozen plants), else numba's thread count. The pool
sleeps while it waits (etb_gym.integrate.configure_thread_pool), so on a shared machine it costs no
more CPU than one thread and still uses whatever the other core has left: measured on the loaded 2-core
machine of docs/speed.md, N = 1024 stepped 690k plant-steps/s with 2 threads vs 455k with 1 (N = 256:
470k vs 348k; N = 64: 233k vs 202k). Results do not depend on it.
"""
from __future__ import annotations

import math

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from etb_gym.components.sensor import delay_push, sense
from etb_gym.jit import HAVE_NUMBA, kernel
from etb_gym.plant import read_only
from etb_gym.threadpool import ensure_thread_pool

from .env import ETBEnv
from .kernel import INFO_KEYS, NOISE_BLOCK, RAD2DEG, step_reward
from .observation import encode_current_into, encode_into, encode_supply_into

SERIAL_UP_TO = 4      # up to this many plants: the single env's compiled control step in a loop
PARALLEL_FROM = 64    # below this many plants one thread is faster than waking numba's thread pool


# ---------------------------------------------------------------------------------------------- compiled loops
@kernel
def clip_duties(actions, ignored, out):
    """``out`` = the actions clipped to [-1, 1], 0 where ``ignored`` (sub-envs about to be reset). Returns the
    first sub-env with a non-finite action that is not ignored, or -1."""
    bad = -1
    for b in range(out.shape[0]):
        a = float(actions[b])
        if ignored[b]:
            out[b] = 0.0
        elif math.isfinite(a):
            out[b] = min(max(a, -1.0), 1.0)
        else:
            out[b] = 0.0
            if bad < 0:
                bad = b
    return bad


@kernel
def step_rewards(duty, last_duty, X, K, ref_table, max_steps, weights, reward, truncated):
    """After the plants stepped: count the step (K), reward and truncation of every sub-env; ``last_duty``
    becomes ``duty``. ``weights`` = (w_tracking / 90, w_effort, w_chattering / 4), as ETBEnv scales them."""
    for b in range(K.shape[0]):
        k = K[b] + 1
        K[b] = k
        r = ref_table[b, min(k, max_steps)]
        reward[b] = step_reward(r - X[b, 0] * RAD2DEG, duty[b], last_duty[b], weights[0], weights[1], weights[2])
        last_duty[b] = duty[b]
        truncated[b] = k >= max_steps


@kernel
def observe_rows(rows, X, AUX, last_duty, supply_V, K, dt, ref_table, max_steps, delay_buf, delay_pos, noise,
                 noise_pos, noise_std, sensor, observe_current, observe_supply, state_scale, clip, obs_low, obs_high,
                 info_cols, obs, info):
    """Sensing, observation and info of sub-envs ``rows``: the single env's ``_observe`` per row, written to
    ``obs[j]`` and ``info[:, j]`` for ``b = rows[j]`` (the info keys' order: INFO_KEYS, torques, t_s). ``sensor`` = (gain, offset, resolution, current noise std,
    current resolution, supply noise std, supply resolution); ``state_scale`` is empty unless the full state is observed; ``info_cols``: the AUX
    column of each torque key (-1: no such component, 0). Returns how many of the rows used up their noise
    block (the caller draws the next block before their next reading, as the single env does)."""
    used_up = 0
    n_obs = obs.shape[1]
    n_x = state_scale.shape[0]
    for j in range(rows.shape[0]):
        b = rows[j]
        phi_read, delay_pos[b] = delay_push(delay_buf[b], delay_pos[b], X[b, 0])
        pos = min(noise_pos[b], NOISE_BLOCK - 1)    # past the end only in rows about to be reset (outputs replaced)
        noise_pos[b] = pos + 1
        if pos + 1 == NOISE_BLOCK:
            used_up += 1
        s_deg = sense(phi_read, sensor[0], sensor[1], noise_std[b] * noise[b, pos, 0], sensor[2]) * RAD2DEG
        r = ref_table[b, min(K[b], max_steps)]
        d = last_duty[b]
        o = obs[j]
        encode_into(o, s_deg, r, d)
        if observe_current:
            encode_current_into(o, sense(X[b, 2], 1.0, 0.0, sensor[3] * noise[b, pos, 1], sensor[4]))
        if observe_supply:
            encode_supply_into(o, 5 if observe_current else 4,
                               sense(supply_V[b], 1.0, 0.0, sensor[5] * noise[b, pos, 2], sensor[6]))
        for m in range(n_x):
            o[n_obs - n_x + m] = X[b, m] * state_scale[m]
        if clip:
            for m in range(n_obs):
                o[m] = max(min(o[m], obs_high[m]), obs_low[m])
        info[1, j] = s_deg
        info[6, j] = r
    fill_info(rows, X, AUX, last_duty, supply_V, K, dt, info_cols, info)
    return used_up


@kernel
def fill_info(rows, X, AUX, last_duty, supply_V, K, dt, info_cols, info):
    """The rows of the info matrix that observe_rows leaves (all but the sensed angle and the reference), one
    key at a time: the rows lie N * 8 bytes apart, so writing all keys of one sub-env would touch a cache
    line per key in the same cache set (measured: 4x slower at N = 1024)."""
    n = rows.shape[0]
    for j in range(n):
        info[0, j] = X[rows[j], 0] * RAD2DEG
    for j in range(n):
        info[2, j] = X[rows[j], 1] * RAD2DEG
    for j in range(n):
        info[3, j] = X[rows[j], 2]
    for j in range(n):
        info[4, j] = last_duty[rows[j]] * supply_V[rows[j]]
    for j in range(n):
        info[5, j] = last_duty[rows[j]]
    for j in range(n):
        info[7, j] = supply_V[rows[j]]
    for c in range(info_cols.shape[0]):
        col = info_cols[c]
        for j in range(n):
            info[8 + c, j] = AUX[rows[j], col] if col >= 0 else 0.0
    for j in range(n):
        info[info.shape[0] - 1, j] = K[rows[j]] * dt


def _max_threads() -> int:
    if not HAVE_NUMBA:
        return 1
    import numba

    return numba.config.NUMBA_NUM_THREADS


class _Threads:
    """Run numba parallel regions with ``n`` threads inside the block (restores the previous count)."""

    def __init__(self, n):
        self.n, self.prev = n, None

    def __enter__(self):
        if HAVE_NUMBA:
            import numba

            ensure_thread_pool()      # before numba's pool starts, or it spins (etb_gym/threadpool.py)
            self.prev = numba.get_num_threads()
            if self.prev != self.n:
                numba.set_num_threads(self.n)
        return self

    def __exit__(self, *exc):
        if self.prev is not None and self.prev != self.n:
            import numba

            numba.set_num_threads(self.prev)


class ETBVectorEnv(VectorEnv):
    """N ETB envs with shared configuration (the keyword arguments of :class:`ETBEnv`)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, num_threads: int | None = None, **kwargs):
        if not (isinstance(num_envs, (int, np.integer)) and num_envs >= 1):
            raise ValueError(f"num_envs = {num_envs!r}: expected an integer >= 1")
        if num_threads is None:
            num_threads = 1 if num_envs < PARALLEL_FROM else _max_threads()
        elif not (isinstance(num_threads, (int, np.integer)) and 1 <= num_threads <= _max_threads()):
            raise ValueError(f"num_threads = {num_threads!r}: expected an integer in [1, {_max_threads()}]")
        self.num_threads = int(num_threads)
        if kwargs.get("render_mode") is not None:
            raise ValueError(f"render_mode = {kwargs['render_mode']!r}: the native vector env does not render; "
                             "use gym.make_vec(..., vectorization_mode='sync') to render sub-envs")
        kwargs.pop("render_mode", None)
        self.env = env = ETBEnv(**kwargs)       # configuration and episode draws (never stepped)
        self.kernel = kn = env.kernel
        self.num_envs = N = int(num_envs)
        self.render_mode = None
        self.single_observation_space = env.observation_space
        self.single_action_space = env.action_space
        self.observation_space = batch_space(env.observation_space, N)
        self.action_space = batch_space(env.action_space, N)
        p = env.plant
        self.plant = p
        # per sub-env state (row b = sub-env b)
        self._rngs: list = [None] * N
        self._episodes: list = [None] * N
        self._X = np.zeros((N, p.n_states))
        self._AUX = np.zeros((N, len(p.components)))
        self._P = np.tile(kn.P_nominal, (N, 1))
        self._P_read_only = read_only(self._P)  # rhs compiled for read-only P, as for the single env and the plant
        self._V = np.full(N, env.supply_V)
        self._K = np.zeros(N, np.int64)
        self._t0 = np.zeros(N)
        self._d = np.zeros(N)                   # this step's applied duty
        self._duty = np.zeros(N)                # the previous step's
        self._tab = np.zeros((N, env.max_steps + 1))
        self._noise = np.zeros((N, NOISE_BLOCK, kn.noise_cols))
        self._npos = np.zeros(N, np.int64)
        self._noise_std = np.zeros(N)
        self._dbuf = np.zeros((N, kn.delay_length))     # the delay lines (delay_push)
        self._dpos = np.zeros(N, np.int64)
        self._autoreset = np.zeros(N, bool)
        self._refill_pending = False
        self._rows = np.arange(N)
        self._dx = np.empty(p.n_states)
        # constants of the compiled loops
        self._state_scale = kn.observed_state_scale
        torques = kn.info_torques
        self._info_cols = np.array([k for _, k in torques], np.int64)
        self._info_keys = tuple((key, "_" + key) for key in INFO_KEYS + tuple(key for key, _ in torques) + ("t_s",))
        self._started = False
        self._threads = _Threads(self.num_threads)

    # ------------------------------------------------------------------------------ per-row resets
    def _reset_rows(self, rows, seeds, options):
        env = self.env
        for i, s in zip(rows, seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(s)
            rng = self._rngs[i]
            ep = env.draw_episode(rng, options)
            self._episodes[i] = ep
            self._P[i] = ep.P
            self._V[i] = ep.supply_V
            self._X[i] = ep.x0
            self._tab[i] = ep.ref_table
            self._noise_std[i] = ep.noise_std_rad
            self._K[i] = 0
            self._duty[i] = 0.0
            self.kernel.rhs(0.0, self._X[i], 0.0, self._P_read_only[i], self._dx, self._AUX[i])
            self._dbuf[i] = self._X[i, 0]
            self._dpos[i] = 0
            rng.standard_normal(out=self._noise[i])
            self._npos[i] = 0
            self._autoreset[i] = False
        return self._observe(np.asarray(rows, np.int64))

    def _refill_noise(self):
        """Draw the next noise block of every live sub-env that used up its block (lazily, as the single env)."""
        for b in np.flatnonzero((self._npos == NOISE_BLOCK) & ~self._autoreset):
            self._rngs[b].standard_normal(out=self._noise[b])
            self._npos[b] = 0
        self._refill_pending = False

    # ------------------------------------------------------------------------------ sensing and outputs
    def _observe(self, rows):
        """Observations (n, n_obs) and info matrix (n_info, n) of sub-envs ``rows`` (int64 index array)."""
        kn = self.kernel
        obs = np.empty((rows.size, kn.n_obs), np.float32)
        info = np.empty((len(self._info_keys), rows.size))
        used_up = observe_rows(rows, self._X, self._AUX, self._duty, self._V, self._K, kn.dt, self._tab,
                               kn.max_steps, self._dbuf, self._dpos, self._noise, self._npos, self._noise_std,
                               kn.sensor, kn.observe_current, kn.observe_supply, self._state_scale,
                               kn.clip_obs, kn.obs_low, kn.obs_high, self._info_cols, obs, info)
        self._refill_pending |= used_up > 0
        return obs, info

    def _info_dict(self, info, mask):
        """SyncVectorEnv's info layout: each key's array (a row of the info matrix) and its ``_key`` mask."""
        out = {}
        for (key, mkey), values in zip(self._info_keys, info):
            out[key] = values
            out[mkey] = mask
        return out

    def _step_plants(self, d):
        kn, N = self.kernel, self.num_envs
        t0 = np.multiply(self._K, kn.dt, out=self._t0)
        if N <= SERIAL_UP_TO:     # a parallel region costs more than a few plants
            ok = np.empty(N, bool)
            cs, X, V, P, A = kn.control_step, self._X, self._V, self._P, self._AUX
            for i in range(N):
                ok[i] = cs(X[i], d[i], V[i], P[i], t0[i], kn.dt, kn.substeps, kn.switching, kn.pwm_frequency_hz, A[i])
            return ok
        if self.num_threads == 1:
            return self.plant.step_batch(self._X, d, self._V, self._P, t0, self._AUX, parallel=False)
        with self._threads:
            return self.plant.step_batch(self._X, d, self._V, self._P, t0, self._AUX)

    # ------------------------------------------------------------------------------ VectorEnv API
    def reset(self, *, seed=None, options=None):
        N = self.num_envs
        if seed is None:
            seeds = [None] * N
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + k for k in range(N)]
        else:
            seeds = list(seed)
            if len(seeds) != N:
                raise ValueError(f"seed: a list of {len(seeds)} seeds for num_envs = {N}: expected one per sub-env")
        opts = dict(options) if options else {}
        mask = opts.pop("reset_mask", None)
        if mask is None:
            rows = self._rows
        else:
            mask = np.asarray(mask)
            if mask.shape != (N,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(f"options['reset_mask'] must be a bool array of shape ({N},) with a True entry")
            if not self._started:
                raise ValueError("options['reset_mask'] needs a full reset first")
            rows = np.flatnonzero(mask)
        obs_r, info_r = self._reset_rows(rows, [seeds[i] for i in rows], opts or None)
        self._started = True
        if mask is None:
            self._obs = obs_r
            return obs_r.copy(), self._info_dict(info_r, np.ones(N, bool))
        self._obs[rows] = obs_r
        info = np.zeros((len(self._info_keys), N))
        info[:, rows] = info_r
        return self._obs.copy(), self._info_dict(info, mask.copy())

    def step(self, actions):
        if not self._started:
            from gymnasium.error import ResetNeeded

            raise ResetNeeded("call reset() before step()")
        env, N = self.env, self.num_envs
        a = np.asarray(actions)
        if a.dtype != np.float32 and a.dtype != np.float64:     # the dtypes clip_duties is compiled for
            a = a.astype(float)
        if a.shape not in ((N,), (N, 1)):
            raise ValueError(f"actions have shape {a.shape}: expected ({N},) or ({N}, 1), one duty cycle per sub-env")
        a = a.reshape(N)
        d = self._d
        bad = clip_duties(a, self._autoreset, d)
        if bad >= 0:
            raise ValueError(f"actions[{bad}] = {float(a[bad])!r}: expected a finite duty cycle in [-1, 1]")
        ok = self._step_plants(d)
        live = ~self._autoreset
        if not ok.all() and not ok[live].all():
            k = int(np.argmax(~ok & live))
            raise FloatingPointError(f"sub-env {k}: "
                                     + self.plant.divergence_message(self._X[k], (self._K[k] + 1) * env.dt))
        reward = np.empty(N)
        trunc = np.empty(N, bool)
        step_rewards(d, self._duty, self._X, self._K, self._tab, env.max_steps, self.kernel.reward_weights, reward,
                     trunc)
        if self._refill_pending:
            self._refill_noise()
        obs, info = self._observe(self._rows)
        if not live.all():
            resets = np.flatnonzero(~live)
            obs_r, info_r = self._reset_rows(resets, [None] * resets.size, None)
            obs[resets] = obs_r
            info[:, resets] = info_r
            reward[resets] = 0.0
            trunc[resets] = False
        self._autoreset = trunc.copy()
        self._obs = obs
        return obs.copy(), reward, np.zeros(N, bool), trunc, self._info_dict(info, np.ones(N, bool))

    @property
    def episodes(self) -> list:
        """The current :class:`~etb_gym.envs.env.Episode` of every sub-env (what its last reset drew)."""
        return list(self._episodes)

    def close_extras(self, **kwargs):
        self.env.close()
