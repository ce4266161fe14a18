"""A native batched vector env: N throttle plants stepped together in one compiled, parallel call.

    envs = gym.make_vec("ETB-3B-v0", num_envs=1024)            # this class (the id's vector entry point)
    obs, info = envs.reset(seed=0)                               # sub-env k seeded with 0 + k
    obs, rew, term, trunc, info = envs.step(envs.action_space.sample())

It is the same MDP as N :class:`~etb_gym.envs.env.ETBEnv` in a ``SyncVectorEnv``, step for step and bit for
bit (tests/test_envs_vector.py): sub-env k owns a generator seeded like ``SyncVectorEnv`` seeds it
(``seed + k``), draws its episodes with the single env's :meth:`ETBEnv.draw_episode`, and reads its
sensor from noise blocks drawn in the same order. A step is one compiled call,
``vector_step`` (envs/vector_kernel.py), in parallel over the sub-envs: each thread steps its plants (the
composition's stepper, as ``Plant.step_batch`` calls it) and then computes their reward, reading, observation
and info with the single env's kernels (``step_reward``, ``sense``, ``delay_push``, ``observation.encode_into``),
drawing a sub-env's next noise block itself when the current one is used up (envs/noise.py: numpy's PCG64 and
ziggurat in compiled code, the same numbers; each sub-env's generator state travels between its
``np.random.Generator``, which draws its episodes at resets, and the step). Python around it only checks the
actions, resets the sub-envs that were truncated and builds the info dict. All it takes from the single env is its
public :class:`~etb_gym.envs.kernel.EnvKernel` (``env.kernel``: stepper, constants, observation layout) and
its episode draws (tests/test_envs_vector.py checks that this module reads no private attribute of it).
Autoreset is Gymnasium's default ``NEXT_STEP`` mode: the step after a sub-env is truncated resets it
(its action is ignored, reward 0) and returns the reset observation and info. ``info`` is a dict of arrays
with ``_key`` masks, as ``SyncVectorEnv`` builds it. Rendering is not supported here (use
``vectorization_mode="sync"`` to render sub-envs).

``num_threads`` (keyword) sets the threads of the step. Default: 1 below 64 sub-envs (waking a thread pool
costs more than stepping a few dozen plants; one thread runs ``vector_step_serial``, no pool at all), else
numba's thread count. The pool sleeps while it waits (etb_gym.threadpool), so on a shared machine it costs no
more CPU than one thread and still uses whatever the other core has left (docs/speed.md). Results do not
depend on it.
"""
from __future__ import annotations

import math

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from etb_gym.components.sensor import shape_reset
from etb_gym.jit import HAVE_NUMBA, kernel
from etb_gym.plant import read_only
from etb_gym.threadpool import ensure_thread_pool

from .env import ETBEnv
from .kernel import INFO_KEYS, NOISE_BLOCK
from .noise import pcg_words, set_pcg_words
from .vector_kernel import observe_rows, vector_step_for

PARALLEL_FROM = 64    # below this many plants one thread is faster than waking numba's thread pool
INFO_PAD = 8          # the info matrix's rows are N + 8 values apart: N * 8 bytes apart (N = 512, 1024, ...) they
#                       would all fall in one cache set, and a step writes every key of a sub-env together


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


def _max_threads() -> int:
    if not HAVE_NUMBA:
        return 1
    import numba

    return numba.config.NUMBA_NUM_THREADS


def _set_threads(n: int) -> int:
    """Set the threads of numba's parallel regions to ``n`` (if they differ); returns the previous count."""
    if not HAVE_NUMBA:
        return n
    import numba

    prev = numba.get_num_threads()
    if prev != n:
        numba.set_num_threads(n)
    return prev


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
        self._T0 = np.zeros(N)                  # scratch of the step: each plant's start time, stepper state
        self._DX = np.empty((N, 3 * p.n_states))
        self._OK = np.ones(N, bool)
        self._d = np.zeros(N)                   # this step's applied duty
        self._duty = np.zeros(N)                # the previous step's
        self._tab = np.zeros((N, env.max_steps + 1))
        self._noise = np.zeros((N, NOISE_BLOCK, kn.noise_cols))
        self._npos = np.zeros(N, np.int64)
        self._noise_std = np.zeros(N)
        self._words = np.zeros((N, 4), np.uint64)        # each sub-env generator's PCG64 state (envs/noise.py)
        self._dbuf = np.zeros((N, kn.delay_length))     # the delay lines (delay_push)
        self._dpos = np.zeros(N, np.int64)
        self._sline = np.zeros((N, kn.shape_length))   # a plant file's reading maps (shape_reading's state)
        self._spos = np.zeros(N, np.int64)
        self._autoreset = np.zeros(N, bool)
        self._rows = np.arange(N)
        self._obs = np.zeros((N, kn.n_obs), np.float32)
        self._dx = np.empty(p.n_states)
        # constants of the compiled loops
        self._state_scale = kn.observed_state_scale
        torques = kn.info_torques
        self._info_cols = np.array([k for _, k in torques], np.int64)
        self._info_keys = INFO_KEYS + tuple(key for key, _ in torques) + ("t_s",)
        self._mask_keys = tuple("_" + key for key in self._info_keys)
        self._started = False
        self._step_fn = vector_step_for(p, parallel=self.num_threads > 1)
        # vector_step's arguments between the actions and the outputs: the same arrays at every step
        self._step_args = (self._autoreset, self._X, self._P, self._V, self._K, self._AUX, self._T0, self._DX,
                           self._OK, self._duty, kn.dt, kn.substeps, kn.switching, kn.pwm_frequency_hz, self._tab,
                           kn.max_steps, kn.reward_weights, self._dbuf, self._dpos, kn.reading_shape, self._sline,
                           self._spos, self._noise, self._npos,
                           self._noise_std, self._words, kn.sensor, kn.observe_current, kn.observe_supply,
                           self._state_scale, kn.clip_obs, kn.obs_low, kn.obs_high, self._info_cols)
        ensure_thread_pool()      # before numba's pool starts, or it spins (etb_gym/threadpool.py)

    def __setstate__(self, state):
        """The read-only view of P is a view again: pickling stores it as a copy, and a reset writing a drawn P
        into ``_P`` then evaluated the stepper with the old one."""
        self.__dict__.update(state)
        if "_P" in state:
            self._P_read_only = read_only(self._P)

    # ------------------------------------------------------------------------------ per-row resets
    def _reset_rows(self, rows, seeds, options):
        env = self.env
        for i, s in zip(rows, seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(s)
            else:   # the step drew this sub-env's noise blocks from its words since its last reset
                set_pcg_words(self._rngs[i], self._words[i])
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
            self._spos[i] = shape_reset(self._sline[i], self.kernel.reading_shape, self._X[i, 0])
            rng.standard_normal(out=self._noise[i])
            pcg_words(rng, self._words[i])
            self._npos[i] = 0
            self._autoreset[i] = False
        return self._observe(np.asarray(rows, np.int64))

    # ------------------------------------------------------------------------------ sensing and outputs
    def _observe(self, rows):
        """Observations (n, n_obs) and info matrix (n_info, n) of sub-envs ``rows`` (int64 index array)."""
        kn = self.kernel
        obs = np.empty((rows.size, kn.n_obs), np.float32)
        info = np.empty((len(self._info_keys), rows.size))
        observe_rows(rows, self._X, self._AUX, self._duty, self._V, self._K, kn.dt, self._tab, kn.max_steps,
                     self._dbuf, self._dpos, kn.reading_shape, self._sline, self._spos, self._noise, self._npos,
                     self._noise_std, self._words, kn.sensor, kn.observe_current, kn.observe_supply,
                     self._state_scale, kn.clip_obs, kn.obs_low, kn.obs_high, self._info_cols, obs, info)
        return obs, info

    def _info_dict(self, info, mask):
        """SyncVectorEnv's info layout: each key's array (a row of the info matrix) and its ``_key`` mask."""
        out = dict(zip(self._info_keys, info))
        out.update(dict.fromkeys(self._mask_keys, mask))
        return out

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
            self._obs[:] = obs_r
            return obs_r, self._info_dict(info_r, np.ones(N, bool))
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
        ignored = self._autoreset
        reward = np.empty(N)
        trunc = np.empty(N, bool)
        obs = self._obs
        info = np.empty((len(self._info_keys), N + INFO_PAD))
        prev = _set_threads(self.num_threads) if self.num_threads > 1 else 1
        try:
            self._step_fn(d, *self._step_args, reward, trunc, obs, info)
        finally:
            if prev != self.num_threads:
                _set_threads(prev)
        info = info[:, :N]
        ok = self._OK
        if not ok.all() and not (ok | ignored).all():
            k = int(np.argmax(~(ok | ignored)))
            raise FloatingPointError(f"sub-env {k}: "
                                     + self.plant.divergence_message(self._X[k], (self._K[k] + 1) * env.dt))
        if ignored.any():
            resets = np.flatnonzero(ignored)
            obs_r, info_r = self._reset_rows(resets, [None] * resets.size, None)
            obs[resets] = obs_r
            info[:, resets] = info_r
            reward[resets] = 0.0
            trunc[resets] = False
        np.copyto(ignored, trunc)
        return obs.copy(), reward, np.zeros(N, bool), trunc, self._info_dict(info, np.ones(N, bool))

    @property
    def episodes(self) -> list:
        """The current :class:`~etb_gym.envs.env.Episode` of every sub-env (what its last reset drew)."""
        return list(self._episodes)

    def close_extras(self, **kwargs):
        self.env.close()
