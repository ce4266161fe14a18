"""The observation contract shared by the envs, the controllers and the RL policy adapter.

Layout of the observation vector (float32, every entry of order one):

    index  name          physical meaning                              scaling
    0      angle         sensed throttle angle                         (deg - 45) / 45
    1      reference     reference angle                               (deg - 45) / 45
    2      error         reference - sensed angle                      deg / 45
    3      last_duty     duty applied during the previous period       as is, in [-1, 1]
    4      current       sensed coil current (only with observe_current=True)    A / 10
    ...    state         full plant state (only with full_state=True), each entry divided by its scale

Controllers decode with :func:`decode`; nothing else about the env is visible to them.

The scaling is written once, in the kernels :func:`encode_into` and :func:`encode_current_into` (compiled
with numba; the single env and :func:`encode` run their plain-Python ``py_func``, the vector env's compiled
batch loop calls them per row: the same operations, so the same float32 bits).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from etb_gym.jit import kernel, py_func

ANGLE_CENTER_DEG = 45.0
ANGLE_SCALE_DEG = 45.0
CURRENT_SCALE_A = 10.0
BASE_FIELDS = ("angle", "reference", "error", "last_duty")


@dataclass(frozen=True)
class Measurement:
    """What a controller sees in one control period (degrees at this edge)."""

    angle_deg: float
    reference_deg: float
    error_deg: float
    last_duty: float
    current_A: float | None = None


def encode(angle_deg: float, reference_deg: float, last_duty: float, current_A: float | None = None,
           extra: np.ndarray | None = None) -> np.ndarray:
    out = np.empty(4 if current_A is None else 5, np.float32)
    py_func(encode_into)(out, angle_deg, reference_deg, last_duty)
    if current_A is not None:
        py_func(encode_current_into)(out, current_A)
    if extra is not None:
        out = np.concatenate([out, np.asarray(extra, np.float32)])
    return out


def decode(obs, observe_current: bool | None = None) -> Measurement:
    """Decode an observation (or the first row of a batch). ``observe_current`` defaults to
    "the vector has a fifth entry"; pass it explicitly when the full state is also observed."""
    o = np.asarray(obs, dtype=np.float64).reshape(-1)
    if o.size < 4:
        raise ValueError(f"observation has {o.size} entries: expected at least 4 {BASE_FIELDS}")
    has_i = (o.size >= 5) if observe_current is None else observe_current
    return Measurement(
        angle_deg=o[0] * ANGLE_SCALE_DEG + ANGLE_CENTER_DEG,
        reference_deg=o[1] * ANGLE_SCALE_DEG + ANGLE_CENTER_DEG,
        error_deg=o[2] * ANGLE_SCALE_DEG,
        last_duty=float(o[3]),
        current_A=float(o[4] * CURRENT_SCALE_A) if has_i else None,
    )


@kernel
def encode_into(out, angle_deg, reference_deg, last_duty):
    """The base fields of one observation, written into ``out[0:4]`` (float32; the rest is the caller's)."""
    out[0] = (angle_deg - ANGLE_CENTER_DEG) / ANGLE_SCALE_DEG
    out[1] = (reference_deg - ANGLE_CENTER_DEG) / ANGLE_SCALE_DEG
    out[2] = (reference_deg - angle_deg) / ANGLE_SCALE_DEG
    out[3] = last_duty


@kernel
def encode_current_into(out, current_A):
    """The sensed coil current of one observation, written into ``out[4]``."""
    out[4] = current_A / CURRENT_SCALE_A
