"""Closed loops: tables learned from the data kept only where the replay of the recorded voltage says they help.

On a closed-loop recording every fit of the diagnosis uses the observer residual (observer.py), which pulls the
model's angle towards the reading after every sample. A table (refine.py: an angle table, a sensor map) fitted
on it sees only the states the loop visited, and its knots beyond them are free to trade against the nominal
parameters without the observer residual noticing. The replay of the recorded voltage (model.replay_view: open
loop, going on from the model's own state) was fitted by neither the formula model nor the table model, so it
is a held-out check of the table: a table that does not lower its cost by more than the cost's noise is dropped
and the formula model (the greedy selection's fit) is the final model.

Measured (docs/diagnosis.md, "Closed loops: tables checked on the replay (round 20)"): backlash@2 random seed
15, an angle table around limp-home of which the loop visited one side only; the table held 0.03-0.09 N m on
the side the loop never reached (the preload moved against it), observer cost 4824 with the table and
4821 without; the twin replayed its training recording at 1.13x the noise, the formula model at 1.07x, and the
held-out open-loop recording at 14.1x against 2.5x.
"""
from __future__ import annotations

import math

import numpy as np

from . import fit as F
from .model import Data, SimulationFailed, replay_view


def _replay_cost(fr: F.FitResult, rv: Data) -> tuple[float, int]:
    """Sum of squared replay residuals (noise units) of ``fr`` on ``rv`` and their number; (inf, 0) where the
    model cannot replay it."""
    try:
        r = F.evaluate(fr.spec, rv, fr.x)
    except (SimulationFailed, ValueError, FloatingPointError, np.linalg.LinAlgError):
        return math.inf, 0
    return (float(r @ r), int(r.size)) if r.size and np.all(np.isfinite(r)) else (math.inf, 0)


def _learned(shaped) -> list:
    """The kept tables of a refine.Outcome: angle/speed/current tables and sensor maps (family ids)."""
    if shaped is None:
        return []
    return ([f"{r.family_id} ({r.term.id})" for r in shaped.refinements if r.kept]
            + [f"{r.family_id} (sensor {r.kind})" for r in shaped.sensor_maps if r.kept])


def check_tables(formula: F.FitResult, final: F.FitResult, steps_before: list, steps: list, shaped, data: Data,
                 significant=None, note: dict | None = None) -> F.FitResult:
    """``final`` (refine's model: ``formula`` with learned tables) or ``formula`` (the selection's fit, the same
    effects without tables), for recordings that are all scored by the observer (closed loops).

    The tables are dropped (their refinements marked not kept, so the report shows no learned shape and the
    exported twin has none) when on the replay of the recorded voltage, which neither model was fitted on, the
    table model's cost is not lower than the formula model's by more than the noise of that cost (sqrt(2 n), n
    its residuals in noise units), unless the formula model leaves a significant mismatch (``significant``: the
    verdict's test) where the table model leaves none: the check changes the twin, not what the diagnosis says
    the final model accounts for. Applies only where refine kept the selection's effects (no effect dropped, not
    outside the catalogue). ``note`` (a dict) gets the figures (report.json ``replay_tables``)."""
    if not data.recs or not all(rd.residual == "observer" for rd in data.recs):
        return final
    tables = _learned(shaped)
    if not tables or final is formula or shaped.outside or shaped.dropped \
            or [s.id for s in steps] != [s.id for s in steps_before]:
        return final
    rv = replay_view(data)
    (c_tab, n_tab), (c_for, n_for) = _replay_cost(final, rv), _replay_cost(formula, rv)
    margin = math.sqrt(2 * max(n_tab, n_for))
    info = {"tables": tables, "replay_cost_tables": c_tab, "replay_cost_formula": c_for, "margin": margin,
            "kept": True}
    if math.isfinite(c_for) and not c_for - c_tab > margin:
        if significant is not None and significant(formula) and not significant(final):
            info["verdict_guard"] = "the formula model would leave a significant mismatch: tables kept"
        else:
            info["kept"] = False
            for r in shaped.refinements:
                r.kept = False
            for r in shaped.sensor_maps:
                r.kept = False
    if note is not None:
        note.update(info)
    return final if info["kept"] else formula
