"""What a diagnosis returns and when a residual counts as significant: shared by the pipeline (run.py) and the
report writer (report.py), which both import it, so neither imports the other's internals."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..plant import Plant
from . import disturbance as D
from . import fit as F
from . import locate as L
from .model import Data

SCHEMA = "etb-gym/diagnosis/1"
RMS_K = 1.5          # the recording matches when the RMS residual is within RMS_K x the noise floor
QUANT_K = 1.5        # a resolution this much coarser than assumed is reported



@dataclasses.dataclass
class Result:
    report: dict
    data: Data
    nominal_fit: F.FitResult
    final_fit: F.FitResult
    residual_before: list
    residual_after: list
    regimes_before: list
    regimes_after: list
    plant: Plant
    sensor: object
    elapsed_s: float

    @property
    def verdict(self) -> str:
        return self.report["verdict"]


def significant_residual(data: Data, res: list) -> bool:
    for rd, r in zip(data.recs, res):
        if L.windows(rd.rec.t_s, r, rd.noise_deg, rd.tol_deg):
            return True
        tol2 = float(np.mean(rd.tol_deg ** 2)) if rd.tol_deg is not None else 0.0
        if math.sqrt(float(np.mean(r ** 2))) > RMS_K * math.sqrt(rd.noise_deg ** 2 + tol2):
            return True
    return False


def significant_mismatch(data: Data, res: list, plant, sensor, z_ref: float | None = None,
                         ref: list | None = None) -> bool:
    """:func:`significant_residual`, or a persistent structure in the current residual or in the angle
    innovation over steady motion of a recording scored by the observer (a closed loop: the loop hides an
    effect in the angle, not in the current it needed nor while the plate slides; disturbance.py). ``res``: the
    angle residuals of the model (``plant``, ``sensor``). ``z_ref``: the nominal model's deciding z
    (disturbance.deciding_z); a structure that the model has accounted for against it (disturbance.resolved,
    the rule that accepts a candidate for it) no longer counts. ``ref``: the nominal model's Structures
    (disturbance.persistent_mismatch): the model's are then measured on their yardsticks, and ``z_ref``
    defaults to their deciding z."""
    if significant_residual(data, res):
        return True
    if ref is not None and z_ref is None:
        z_ref = D.deciding_z(ref)
    z = D.deciding_z(D.persistent_mismatch(data, plant, sensor, ref=ref))
    return z > D.Z_DETECT and (z_ref is None or not D.resolved(z_ref, z))
