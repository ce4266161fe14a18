"""The observation contract shared by the envs, the controllers and the RL policy adapter.

Layout of the observation vector (float32, every entry of order one):

    index  name          physical meaning                              scaling
    0      angle         sensed throttle angle                         (deg - 45) / 45
    1      reference     reference angle                               (deg - 45) / 45
    2      error         reference - sensed angle                      deg / 45
    3      last_duty     duty applied during the previous period       as is, in [-1, 1]
    4      current       sensed coil current (only with observe_current=True)    A / 10
    4|5    supply        sensed battery voltage (only with observe_supply=True;   V / 10
                         index 5 when the current is observed too)
    ...    state         full plant state (only with full_state=True), each entry divided by its scale

Sensors (``PositionSensorParams``, overridable with the env's ``sensor=`` dict): angle 0.01 deg noise, 12-bit
quantization over 90 deg (0.022 deg); coil current 0.01 A noise (``current_noise_std_A``), no quantization
(``current_resolution_A``); battery voltage 0.05 V noise (``supply_noise_std_V``) and a 10-bit ADC over 20 V
(``supply_resolution_V`` = 0.0195 V), as an engine ECU measures them.

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
SUPPLY_SCALE_V = 10.0
BASE_FIELDS = ("angle", "reference", "error", "last_duty")


@dataclass(frozen=True)
class Measurement:
    """What a controller sees in one control period (degrees at this edge)."""

    angle_deg: float
    reference_deg: float
    error_deg: float
    last_duty: float
    current_A: float | None = None
    supply_V: float | None = None


def encode(angle_deg: float, reference_deg: float, last_duty: float, current_A: float | None = None,
           extra: np.ndarray | None = None, supply_V: float | None = None) -> np.ndarray:
    out = np.empty(4 + (current_A is not None) + (supply_V is not None), np.float32)
    py_func(encode_into)(out, angle_deg, reference_deg, last_duty)
    if current_A is not None:
        py_func(encode_current_into)(out, current_A)
    if supply_V is not None:
        py_func(encode_supply_into)(out, out.size - 1, supply_V)
    if extra is not None:
        out = np.concatenate([out, np.asarray(extra, np.float32)])
    return out


def decode(obs, observe_current: bool | None = None, observe_supply: bool = False) -> Measurement:
    """Decode an observation (or the first row of a batch). ``observe_current`` defaults to
    "the vector has an entry after the supply's"; pass both flags as the env was made when the full
    state is also observed."""
    o = np.asarray(obs, dtype=np.float64).reshape(-1)
    has_v = bool(observe_supply)
    need = 4 + has_v
    if o.size < need:
        raise ValueError(f"observation has {o.size} entries: expected at least {need} "
                         f"{BASE_FIELDS + (('supply',) if has_v else ())}")
    has_i = (o.size >= need + 1) if observe_current is None else bool(observe_current)
    if o.size < need + has_i:
        raise ValueError(f"observation has {o.size} entries: expected at least {need + has_i} with the current")
    return Measurement(
        angle_deg=o[0] * ANGLE_SCALE_DEG + ANGLE_CENTER_DEG,
        reference_deg=o[1] * ANGLE_SCALE_DEG + ANGLE_CENTER_DEG,
        error_deg=o[2] * ANGLE_SCALE_DEG,
        last_duty=float(o[3]),
        current_A=float(o[4] * CURRENT_SCALE_A) if has_i else None,
        supply_V=float(o[4 + has_i] * SUPPLY_SCALE_V) if has_v else None,
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


@kernel
def encode_supply_into(out, index, supply_V):
    """The sensed battery voltage of one observation, written into ``out[index]`` (4, or 5 after the current)."""
    out[index] = supply_V / SUPPLY_SCALE_V
