"""Shapes from the data: a named family's formula refined by a regularized lookup table (docs/diagnosis-shapes.md).

A *map term* is a table component of ``etb_gym.components.effects_maps`` on a knot grid taken from the plant
and the data (the angle knots span the plant's own stops, the speed and current knots the range the
recordings visit). Its knot values are the fitted coefficients c, found by output error together with the
calibrated nominal parameters (the model's other parameters stay at their fitted values):

    minimize  |r(x)|^2 + lambda |D c|^2 + |x_nom / sigma|^2
                                  r: the diagnosis's normalized residual (fit.make_fun)
                                  D: second differences of the knot values (roughness)
                                  x_nom: the nominal parameters, 0 at the nameplate (sigma: NOMINAL_PRIOR of it)

by Gauss-Newton on a finite-difference Jacobian (the table is linear in c, but a formula fit far from the
optimum, its nominal parameters bent to the wrong shape, needs more than three iterations: up to GN_ITER). The roughness weight lambda is chosen by cross-validation over the diagnosis's two folds of
alternating 0.5 s time blocks: for each lambda on a log grid the linearized problem is solved on one fold
and the angle residual predicted on the other (``fit.fold_masks`` layout). The *held-out error* of a model
(formula or map) is measured the same way for both, but with the true simulation on the held-out fold:
every free parameter refitted on one fold by one regularized Gauss-Newton step from the full-data optimum,
the other fold's angle residual simulated, summed over both folds (:func:`heldout_error`).

A refined map is kept (in the twin and the exported plant file, where it sits beside the family's formula
as a correction) only when its held-out error is lower than the formula's by MIN_GAIN.

Where the recordings did not go the table is not identified, and the roughness penalty alone would extrapolate
the last visited slope (a straight line in the correction, out to the stop). Such knots (less than VISIT_MIN_S of
hat-weighted time near them, :func:`visit_time_s`) are *anchored*: pulled to 0 with ANCHOR times the weight of a
roughness row, so the twin falls back to the family's formula (or, for the generic tables, to the calibrated
nominal model) where the recordings did not go. Beyond the visited range a family's table over angle does not
return to the formula but holds formula + table at its value at the last visited knot (:func:`hold_rows`): a
formula fitted to part of the stroke is not extrapolated (docs/diagnosis-history.md, round 14). The same holds for knots the recordings visited without seeing them:
where the plate sits against a stop or in the spring's limp-home band a torque change does not move it, so a
knot whose Jacobian column has less than ID_MIN of its table's median energy (first linearization of
:func:`fit_penalized`) is anchored as well (measured: an airflow plateau's table, free at the 0 and 6 deg knots,
put 5-9 mN m at limp-home and the closed stop, where a closed loop holds the plate: 0.9 deg off there). Speed and current tables get an extra knot beyond the range the
recordings visited for the same reason (a table is held constant beyond its last knot).
"""
from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from ..components import effects_maps as mx
from . import fit as F
from .candidates import Candidate, FitParam
from .model import Data, Spec, _layout, residuals, simulate

MIN_GAIN = 0.05          # a map replaces the formula only if the held-out error falls by at least this fraction
LAMBDAS = tuple(10.0 ** np.arange(-3.0, 3.5, 0.5))   # roughness weights (relative, see _penalty_scale)
GN_ITER = 8             # Gauss-Newton iterations at most (stops when the objective falls by < 0.5 %)
FD_STEP = 0.5            # finite-difference step in normalized units (a knot value moves by FD_STEP * scale)
ANGLE_KNOTS = 16         # knots of a refined angle map over the stroke
PROFILE_KNOTS = 17       # knots of a torque-constant profile over the stroke (5.6 deg on 3B)
FRICTION_ANGLE_KNOTS = 33  # at most this many knots of a friction level over the stroke: PROFILE_KNOTS' 17 and one
                           # between each pair where the recordings dwelt (2.8 deg on 3B; friction_angle_grid)
JAC_SUBSTEPS = 20       # Jacobians at this integrator step (the residual at the model's own)
RIDGE = 1e-4             # a small pull of the table towards zero (collinearity with the spring)
VISIT_MIN_S = 0.02       # a knot the recordings spent less time near (hat-weighted) is not identified by them ...
ANCHOR = 1e3             # ... and is pulled to 0 (the formula alone) with this weight, relative to a roughness row
ID_MIN = 0.01           # a knot whose Jacobian column carries less than this share of its table's median is not
                         # identified either (the plate pinned at a stop or in the limp-home band): anchored too
NEAR_ZERO = (0.02, 0.08)  # extra current knots near 0, as fractions of the visited extent (signed_knots)
OUTER_SPEED = 3.0        # speed tables get a last knot at this multiple of the fastest speed visited (anchored)
STRIBECK_SPAN = 3e3      # the Stribeck table's knots reach this far below the top speed (0.033 rad/s at 100 rad/s:
                         # a rig's Stribeck velocity is 0.02-0.2 rad/s; at top / 300 the first knot, 0.33 rad/s,
                         # left the whole drop in one interval; stribeck_friction@2 3B s22, docs/diagnosis-history.md round 22)
THERMAL_BRANCHES = 7     # branches of the coil heating's thermal network (thermal_term) ...
THERMAL_TAU_MIN = 0.2    # ... the fastest time constant [s] ...
THERMAL_SPAN = 3.0       # ... the slowest, this multiple of the longest recording
LOG_GRIDS = ("time_constant_s",)   # grids whose roughness is taken over the log of the knots
STRIBECK_FLOOR = 0.01    # ... but not below this speed (0.6 deg/s: the recordings' speeds are not resolved there; at
                         # top/3e3 = 0.0016 rad/s the table's lowest knots bent the closing level by -3 mN m and the
                         # twin went 6.3x -> 10.9x on stribeck_friction@2 random s22's closed-loop held-out recording)


# ------------------------------------------------------------------------------------ map terms
@dataclasses.dataclass
class MapTerm:
    """One table: its component class, grid and value fields; coefficients are the knot values."""

    id: str                       # candidate id inside the Spec (e.g. "airflow_torque_map")
    family: str
    cls: type
    grid: np.ndarray
    value_fields: tuple
    scale: float                  # typical knot value (normalization of the coefficients)
    unit: str
    fixed: tuple = ()             # other fields of the component ((name, value), ...)
    basis: np.ndarray | None = None   # knot values (value fields in order, flattened) = basis @ coefficients;
                                      # None: the coefficients are the knot values (a nested, tied form otherwise:
                                      # :func:`direction_split_term`)
    score_current: bool = False   # the folds score the current residual too, not the angle's alone (a term of
                                  # the coil's voltage balance whose evidence is the current: thermal_term)
    split_start: bool = False     # the fit starts from the best point of a grid over the torque constant and the
                                  # back-EMF constant apart (:func:`split_start`): torque_emf_term

    @property
    def n_coef(self) -> int:
        return self.grid.size * len(self.value_fields) if self.basis is None else self.basis.shape[1]

    def values(self, coef) -> np.ndarray:
        """The knot values of every value field (flattened, fields in order) for coefficients ``coef``."""
        c = np.asarray(coef, float)
        return c if self.basis is None else self.basis @ c

    def roughness(self) -> np.ndarray:
        """Second differences of the knot values, per value field, in normalized coefficients (through the
        basis where there is one: a direction offset constant over the grid has none)."""
        if self.basis is not None:
            R = dataclasses.replace(self, basis=None).roughness()
            return R @ self.basis if R.size else np.zeros((0, self.n_coef))
        n = self.grid.size
        if n < 3:
            return np.zeros((0, self.n_coef))
        h = np.diff(np.log(self.grid) if self.cls.grid_field in LOG_GRIDS else self.grid)
        rows = []
        for f in range(len(self.value_fields)):
            for k in range(1, n - 1):
                r = np.zeros(self.n_coef)
                # divided second difference on a possibly non-uniform grid, scaled to a uniform grid's
                a, b = h[k - 1], h[k]
                m = 0.5 * (a + b)
                r[f * n + k - 1] = m / a
                r[f * n + k] = -m / a - m / b
                r[f * n + k + 1] = m / b
                rows.append(r)
        return np.array(rows)

    def candidate(self) -> Candidate:
        fit = tuple(FitParam(f"c{k}", 0.0, -1e3 * self.scale, 1e3 * self.scale, self.scale, self.unit)
                    for k in range(self.n_coef))
        return Candidate(self.id, self.family, self.cls.description, fit, component=_Factory(self))

    def component(self, coef) -> mx.Effect:
        return _Factory(self).make(np.asarray(coef, float))


class _Factory:
    """Stands in for an effect class inside a Candidate: ``Params(c0=..., c1=...)`` -> the table's params."""

    def __init__(self, term: MapTerm):
        self.term = term

    def make(self, coef):
        t = self.term
        n = t.grid.size
        kw = {t.cls.grid_field: tuple(t.grid)}
        vals = t.values(coef)
        for j, f in enumerate(t.value_fields):
            kw[f] = tuple(vals[j * n:(j + 1) * n])
        kw.update(dict(t.fixed))
        comp = t.cls(t.cls.Params(**kw))
        comp.name = t.id                     # unique in the plant (two tables of one kind may coexist)
        return comp

    def Params(self, **kw):
        return np.array([kw[f"c{k}"] for k in range(self.term.n_coef)])

    def __call__(self, coef):
        return self.make(coef)


def data_angles_rad(data: Data) -> np.ndarray:
    return np.radians(np.concatenate([rd.rec.angle_deg for rd in data.recs]))


def data_speeds_rad_s(data: Data) -> np.ndarray:
    from .measurement import smooth
    return np.concatenate([np.gradient(np.radians(smooth(rd.rec.angle_deg, 15)), rd.rec.dt_s) for rd in data.recs])


def angle_grid(base, data: Data, n: int, limp_home: bool = False) -> np.ndarray:
    """n knots over the plant's stroke (its stops; the visited range if the plant has none); with ``limp_home``
    the knot nearest the plant's limp-home angle is moved onto it (a torque table meets the spring there)."""
    phi = data_angles_rad(data)
    lo = base.angle_min_rad if math.isfinite(base.angle_min_rad) else float(np.min(phi))
    hi = base.angle_max_rad if math.isfinite(base.angle_max_rad) else float(np.max(phi))
    g = np.linspace(lo, hi, n)
    lh = _lh(base)
    if limp_home and math.isfinite(lh) and lo < lh < hi:
        k = int(np.argmin(np.abs(g - lh)))
        if 0 < k < n - 1 and abs(g[k] - lh) < 0.25 * (g[1] - g[0]):
            g[k] = lh              # a knot close by moves onto limp-home (the grid stays nearly uniform) ...
        else:                      # ... else one more knot (never moving a stop's)
            g = np.sort(np.append(g, lh))
    return g


def friction_angle_grid(base, data: Data) -> np.ndarray:
    """The knots of a friction level over angle: the profile grid (PROFILE_KNOTS over the stroke) and, between two
    of its knots, the midpoint (FRICTION_ANGLE_KNOTS in all) where the recordings spent VISIT_MIN_S near it and
    near both of them (hat-weighted on the fine grid: a midpoint narrows its neighbours' hats, and a profile
    knot left unvisited by that would be anchored to the formula alone in the middle of the table). A plate at rest sticks where drive - spring = friction, 0.16 deg per mN m on
    3B, and a friction band 4-8 deg wide between 5.6 deg knots is 1-4 mN m off between them
    (angle_dependent_friction@1 3B open s32: the best 17-knot table replays the held-out at 2.4x, the best 33-knot
    one at 1.6x). Where the recordings only passed, a midpoint would not be identified (a closed loop's fit put
    14-22 mN m spikes there, or the formula alone where it was anchored), so the grid stays coarse there
    (docs/diagnosis-history.md, round 27 r27friction)."""
    fine = angle_grid(base, data, FRICTION_ANGLE_KNOTS)
    dt = float(np.mean([rd.rec.dt_s for rd in data.recs]))
    seen = _hat_time(data_angles_rad(data), fine, dt) >= VISIT_MIN_S
    keep = np.ones(fine.size, bool)
    keep[1::2] = seen[1::2] & seen[:-1:2] & seen[2::2]      # and its two profile knots (their hats narrow too)
    return fine[keep]


def _lh(base) -> float:
    """The plant's limp-home angle (nan without a spring)."""
    return base.limp_home_rad if base.spring is not None else math.nan


def local_angle_grid(base, centre_rad: float, below_deg: float, above_deg: float, step_deg: float = 0.5) -> np.ndarray:
    """Knots every ``step_deg`` from ``below_deg`` under to ``above_deg`` over ``centre_rad``, inside the plant's
    stroke (a contact's neighbourhood: limp-home, a stop). The table holds its end values beyond the grid, as a
    contact's torque change does (a backlash shifts the spring's torque by a constant beyond the play)."""
    lo = max(centre_rad - math.radians(below_deg), base.angle_min_rad if math.isfinite(base.angle_min_rad) else -math.inf)
    hi = min(centre_rad + math.radians(above_deg), base.angle_max_rad if math.isfinite(base.angle_max_rad) else math.inf)
    n = max(int(round(math.degrees(hi - lo) / step_deg)) + 1, 3)
    return np.linspace(lo, hi, n)


def speed_grid(data: Data, n: int = 7, floor_rad_s: float | None = None) -> np.ndarray:
    """0 and n-1 knots spaced logarithmically from the fastest speed the recordings reach down to 300 times less,
    and one at OUTER_SPEED times that (not visited: anchored, so the table returns to the formula beyond the data).
    With ``floor_rad_s`` the knots reach down to that speed (never less than 1/STRIBECK_SPAN of the top, never
    above top/300) at the same log spacing (more knots)."""
    w = np.abs(data_speeds_rad_s(data))
    top = max(float(np.quantile(w, 0.995)), 0.5)
    if floor_rad_s is None:
        return np.concatenate([[0.0], np.geomspace(top / 300.0, top, n - 1), [OUTER_SPEED * top]])
    low = min(top / 300.0, max(top / STRIBECK_SPAN, floor_rad_s))
    m = max(n - 1, int(round(math.log(top / low) / (math.log(300.0) / (n - 2)))) + 1)
    return np.concatenate([[0.0], np.geomspace(low, top, m), [OUTER_SPEED * top]])


def current_grid(data: Data, base, n: int = 9, by_extent: bool = False) -> np.ndarray:
    """n signed knots over the currents the recordings reach (measured, else the supply over R); with a measured
    current also knots at the stall current +-V/R where that lies beyond (anchored: not visited). Half the
    intervals on each side of 0, or with ``by_extent`` in proportion to each side's extent (at least one each:
    one spacing over the visited range, :func:`signed_knots`)."""
    cur = [rd.rec.current_A for rd in data.recs if rd.rec.current_A is not None]
    if cur:
        c = np.concatenate(cur)
        lo, hi = float(np.quantile(c, 0.002)), float(np.quantile(c, 0.998))
    else:
        R = float(getattr(base.drive.params, "resistance_ohm", 1.0))
        v = max(float(np.max(np.abs(rd.rec.voltage_V))) for rd in data.recs)
        lo, hi = -v / R, v / R
    top = max(abs(lo), abs(hi), 0.1)
    lo = min(lo, -0.05 * top)
    hi = max(hi, 0.05 * top)
    if by_extent:
        g = signed_knots(lo, hi, n)
    else:
        g = np.unique(np.concatenate([np.linspace(lo, 0.0, (n + 1) // 2), np.linspace(0.0, hi, (n + 1) // 2)]))
    if cur:                       # beyond the measured range, up to the stall current (anchored knots)
        R = float(getattr(base.drive.params, "resistance_ohm", 0.0) or 0.0)
        v = max(float(np.max(np.abs(rd.rec.voltage_V))) for rd in data.recs)
        stall = v / R if R > 0 else 0.0
        ext = [x for x in (-stall, stall) if abs(x) > 1.2 * max(abs(lo), abs(hi))]
        g = np.unique(np.concatenate([g, ext]))
    return g


def signed_knots(lo: float, hi: float, n: int) -> np.ndarray:
    """n knots from ``lo`` < 0 to ``hi`` > 0 with one at 0, the n - 1 intervals shared between the two sides in
    proportion to their extent (at least one each), so the spacing is about the same on both: a closed loop's
    current is nearly all of one sign, and half the knots on the side it hardly visits left 1.5 A between the
    knots where it does (supply_drop@1 3B s15 closed; docs/diagnosis-history.md, round 21)."""
    m = max(n - 1, 2)
    k_lo = int(np.clip(round(m * -lo / (hi - lo)), 1, m - 1))
    g = np.concatenate([np.linspace(lo, 0.0, k_lo + 1), np.linspace(0.0, hi, m - k_lo + 1)])
    # near the current's sign change, where a drop's forward voltage or a direction-dependent term switches, two
    # more knots on each side (NEAR_ZERO of the larger side's extent) inside the first interval
    top = max(-lo, hi)
    near = [s * f * top for f in NEAR_ZERO for s in (-1.0, 1.0)]
    first = (g[k_lo - 1], g[k_lo + 2])        # the intervals either side of 0 (g holds 0 twice here)
    g = np.concatenate([g, [x for x in near if first[0] < x < first[1]]])
    return np.unique(g)


def hat_weights(x: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A table's piecewise-linear interpolation (effects_maps' lookup) as weights: per sample of ``x`` the knot
    ``k`` to its left and the fraction ``f`` towards knot ``k + 1`` (weights 1 - f and f; held at the end knots
    beyond the grid). ``grid``: increasing, at least 2 knots."""
    xc = np.clip(x, grid[0], grid[-1])
    k = np.clip(np.searchsorted(grid, xc, side="right") - 1, 0, grid.size - 2)
    return k, (xc - grid[k]) / (grid[k + 1] - grid[k])


def _hat_time(x: np.ndarray, grid: np.ndarray, dt: float) -> np.ndarray:
    """Per knot: the time [s] the samples ``x`` spent near it, each sample split between its two knots as the
    table's interpolation weights it (samples beyond an end count for the end knot)."""
    g = np.asarray(grid, float)
    out = np.zeros(g.size)
    if x.size == 0 or g.size < 2:
        return out + x.size * dt
    k, f = hat_weights(x, g)
    np.add.at(out, k, (1.0 - f) * dt)
    np.add.at(out, k + 1, f * dt)
    return out


def visit_time_s(term: "MapTerm", data: Data) -> np.ndarray | None:
    """Per coefficient of ``term`` (value fields in order): the hat-weighted time the recordings spent near the
    knot, in the table's own variable (angle, speed per direction, current). None: not known (no current
    recorded for a current table; another grid). With a basis, a coefficient's time is the sum over the knots it
    moves (a direction offset: every knot of both directions)."""
    if term.basis is not None:
        v = visit_time_s(dataclasses.replace(term, basis=None), data)
        return None if v is None else (np.abs(term.basis) > 0).T.astype(float) @ v
    dts = np.concatenate([np.full(rd.rec.n, rd.rec.dt_s) for rd in data.recs])
    field = term.cls.grid_field
    if field == "angle_rad":
        t = _hat_time(data_angles_rad(data), term.grid, float(np.mean(dts)))
        return np.tile(t, len(term.value_fields))
    if field == "speed_rad_s":
        w = data_speeds_rad_s(data)
        out = []
        for f in term.value_fields:
            sel = w > 0 if "opening" in f else (w < 0 if "closing" in f else np.ones(w.size, bool))
            out.append(_hat_time(np.abs(w[sel]), term.grid, float(np.mean(dts))))
        return np.concatenate(out)
    if field == "current_A":
        cur = [rd.rec.current_A for rd in data.recs]
        if any(c is None for c in cur):
            return None
        return np.tile(_hat_time(np.concatenate(cur), term.grid, float(np.mean(dts))), len(term.value_fields))
    return None


def angle_torque_term(tid: str, family: str, base, data: Data, n: int, scale: float) -> MapTerm:
    """A torque-over-angle table over the stroke with a knot at limp-home. The data above limp-home see the
    spring's preload and rate only as a sum with the table; with a knot there, a table that the recordings do not
    identify at limp-home (the plate held in the spring's contact band: :func:`anchor_unidentified`) is held at 0
    from limp-home down, so the preload carries the torque at limp-home and, mirrored, below it."""
    return MapTerm(tid, family, mx.AngleTorqueMap, angle_grid(base, data, n, limp_home=True), ("torque_Nm",),
                   scale, "N m")


# which table refines which family's formula
def family_terms(cid: str, base, data: Data) -> list:
    """The maps that may refine candidate ``cid`` (the one with the lowest held-out error is tried):
    :func:`family_term`'s, and for a torque-constant error also one over current (a constant that saturates
    or differs by current direction)."""
    t = family_term(cid, base, data)
    out = [t] if t is not None else []
    if t is not None and t.family == "friction":       # every friction family: a level that differs by direction
        out.append(direction_split_term(t) if t.cls is mx.SpeedFrictionMap else direction_offset_term(cid))
    if cid == "coil_heating":            # losses that go with the voltage as well as the copper loss (the folds decide)
        out.append(thermal_term(cid, base, data, voltage=True))
    if cid == "torque_constant_error":
        grid = current_grid(data, base, 9, by_extent=True)
        out.append(MapTerm(f"{cid}_current_map", "electrical", mx.CurrentTorqueConstantMap, grid,
                           ("delta_Nm_per_A",), 0.002, "N m/A"))
        # the same over current for the torque alone, the back-EMF left to the formula's constant: a constant
        # that differs by current direction (armature reaction) while the induced voltage does not; in the
        # form above its back-EMF follows the table (round 23: the truth's torque in that form replays
        # torque_constant_error@2 3B s24 at 7.05x the noise, the truth at 1.03x)
        out.append(MapTerm(f"{cid}_current_torque_map", "electrical", mx.CurrentTorqueMap, grid,
                           ("delta_Nm_per_A",), 0.002, "N m/A"))
        out.append(torque_emf_term(cid, data))
    return out


# torque constant and back-EMF constant apart (torque_emf_term, split_start): the grid's steps, shares of c_M
SPLIT_TORQUE = (-0.02, -0.01, -0.005, 0.0, 0.005, 0.01, 0.02)   # the torque constant's (spring, friction co-scaled)
SPLIT_EMF = (-0.005, -0.0025, 0.0, 0.0025, 0.005)                # the back-EMF constant's (the torque unchanged)
SPLIT_NFEV = 40          # the local fit from the grid's best point
EMF_KNEE = NEAR_ZERO[0]  # torque_emf_term's knots at -+ this share of the largest current visited


def torque_emf_term(cid: str, data: Data | None = None) -> MapTerm:
    """A torque per ampere added to the formula's, one value for each direction of the current (knots at -+e,
    e = EMF_KNEE of the largest current visited; the table holds each value beyond), the back-EMF left to the
    formula's constant: a torque constant that differs from the back-EMF constant. For a PM motor both are the flux
    linkage, but the torque constant is taken under load (armature reaction, saturation by the coil's own field)
    and the back-EMF constant at zero current: a rig's measured k_t and k_e differ by a few per cent. The formula
    ties them, and its fit settles between the two: torque_constant_error@2 3B s33 closed, the truth's torque
    +0.00425 N m/A, its back-EMF +0.00266, the formula's +0.00304 (twin 2.31x on the open-loop held-out recording;
    the split at the truth's values 1.08x). A direction the recordings did not drive the current in is not
    identified (shapes.anchor_unidentified) and falls back to the formula there: the back-EMF constant. A table over
    current has the same freedom, but its roughness holds the step at 0 A and the fit left it at 0."""
    top = 1.0
    cur = [rd.rec.current_A for rd in (data.recs if data is not None else ()) if rd.rec.current_A is not None]
    if cur:
        c = np.abs(np.concatenate(cur))
        top = max(float(np.quantile(c, 0.998)), 0.1)
    e = EMF_KNEE * top
    return MapTerm(f"{cid}_torque_offset", "electrical", mx.CurrentTorqueMap, np.array([-e, e]),
                   ("delta_Nm_per_A",), 0.002, "N m/A", split_start=True)


def direction_split_term(term: MapTerm) -> MapTerm:
    """``term`` (a friction table over speed with independent opening and closing branches) in its nested form:
    one shape over speed shared by both directions, m(|omega|), plus a level offset d constant over speed,
    opening m + d and closing m - d (n + 1 coefficients instead of 2 n; d = 0 is the symmetric table). A rig's
    friction may differ by direction (the return spring's preload loads the bearings one way; seals): with
    independent branches each direction's level is as rough as its shape, and the cross-validation's one weight
    cannot keep a direction offset while smoothing the shape (docs/diagnosis-history.md, round 24 e24friction)."""
    n = term.grid.size
    B = np.zeros((2 * n, n + 1))
    B[:n, :n] = np.eye(n)
    B[n:, :n] = np.eye(n)
    B[:n, n], B[n:, n] = 1.0, -1.0
    return dataclasses.replace(term, id=f"{term.id}_split", basis=B)


def direction_offset_term(cid: str) -> MapTerm:
    """A friction level offset by direction alone, for a friction family whose table is not over speed (its
    formula keeps its own shape): one coefficient d, the level +d while opening and -d while closing at every
    speed (a SpeedFrictionMap whose two knots hold the same value)."""
    B = np.array([[1.0], [1.0], [-1.0], [-1.0]])
    return MapTerm(f"{cid}_direction_map", "friction", mx.SpeedFrictionMap, np.array([0.0, 1.0]),
                   ("opening_Nm", "closing_Nm"), 0.005, "N m", (("presliding_rad", 2e-3),), basis=B)


def thermal_grid(data: Data, n: int = THERMAL_BRANCHES) -> np.ndarray:
    """n time constants, log-spaced from THERMAL_TAU_MIN to THERMAL_SPAN times the longest recording: a branch
    slower than the recording acts on it as a ramp, faster ones as the winding's own heating."""
    return np.geomspace(THERMAL_TAU_MIN, max(THERMAL_SPAN * data.longest_s, 10.0 * THERMAL_TAU_MIN), n)


def thermal_term(cid: str, base, data: Data, voltage: bool = False) -> MapTerm:
    """The heating as a Foster network (components/effects_thermal.py): a thermal resistance per fixed time
    constant, driven by the copper loss at the plant's resistance; roughness over log tau. Any heating dynamics
    (one node, a winding and a housing node, a distributed housing) is a linear combination of the branches.
    With ``voltage`` the branches are driven by u^2 too (a second column of coefficients, losses that go with the
    coil voltage: PWM ripple, iron), else that column is held at 0 (a basis)."""
    from ..components.effects_thermal import ThermalNetwork
    from ..variants import COPPER_ALPHA_PER_K
    r0 = float(getattr(base.drive.params, "resistance_ohm", 1.0))
    g = thermal_grid(data)
    n = g.size
    B = np.eye(2 * n) if voltage else np.vstack([np.eye(n), np.zeros((n, n))])
    return MapTerm(f"{cid}_{'voltage_' if voltage else ''}map", "electrical", ThermalNetwork, g,
                   ("thermal_resistance_K_per_W", "voltage_rise_K_per_V2"), 1.0, "K/W, K/V^2",
                   (("cold_resistance_ohm", r0), ("temperature_coefficient_per_K", COPPER_ALPHA_PER_K)), basis=B,
                   score_current=any(rd.rec.current_A is not None for rd in data.recs))


def family_term(cid: str, base, data: Data) -> MapTerm | None:
    """The map that refines candidate ``cid`` (None: the family has no table form here)."""
    if cid in ("airflow_torque", "spring_asymmetry"):
        return angle_torque_term(f"{cid}_map", "mechanical", base, data, ANGLE_KNOTS, 0.005)
    if cid in ("shaft_flux_loss", "torque_constant_error"):
        return MapTerm(f"{cid}_map", "magnetic", mx.TorqueConstantMap, angle_grid(base, data, PROFILE_KNOTS),
                       ("delta_Nm_per_A",), 0.002, "N m/A")
    if cid == "angle_dependent_friction":
        return MapTerm(f"{cid}_map", "friction", mx.AngleFrictionMap, friction_angle_grid(base, data),
                       ("level_Nm",), 0.005, "N m", (("presliding_rad", 2e-3),))
    if cid == "stribeck_friction":         # its drop lies far below the top speed: STRIBECK_SPAN, same spacing
        return MapTerm(f"{cid}_map", "friction", mx.SpeedFrictionMap, speed_grid(data, 7, STRIBECK_FLOOR),
                       ("opening_Nm", "closing_Nm"), 0.005, "N m", (("presliding_rad", 2e-3),))
    if cid == "coil_heating":
        return thermal_term(cid, base, data)
    if cid == "supply_drop":
        return MapTerm(f"{cid}_map", "electrical", mx.CurrentVoltageMap, current_grid(data, base, 9, by_extent=True),
                       ("drop_V",), 0.02, "V")
    if cid == "inductance_saturation":
        return MapTerm(f"{cid}_map", "electrical", mx.CurrentInductanceMap, current_grid(data, base, 9, by_extent=True),
                       ("delta_H",), 0.0005, "H")
    if cid == "backlash" and math.isfinite(base.limp_home_rad):     # the springs' torque around limp-home
        return MapTerm(f"{cid}_map", "mechanical", mx.AngleTorqueMap,
                       local_angle_grid(base, base.limp_home_rad, 4.0, 4.0), ("torque_Nm",), 0.005, "N m")
    if cid == "end_stop_compliance" and math.isfinite(base.angle_max_rad):   # a contact before the open stop
        return MapTerm(f"{cid}_map", "mechanical", mx.AngleTorqueMap,
                       local_angle_grid(base, base.angle_max_rad, 6.0, 0.0), ("torque_Nm",), 0.02, "N m")
    return None


# ------------------------------------------------------------------------------------ penalized Gauss-Newton
@dataclasses.dataclass
class Problem:
    """A model (spec), the normalized parameters x, which of them are free, and the roughness rows of each
    table (one roughness weight per table)."""

    spec: Spec
    x: np.ndarray
    free: np.ndarray                      # indices into x
    groups: list                          # per table: (D rows over the free parameters, ridge mask over them,
                                          #             anchor mask: 1 knots the data did not visit, -1 knots
                                          #             held by hold_rows; (hold rows H, their targets b))
    prior: np.ndarray | None = None       # per free parameter: weight of its pull to x = 0 (the nameplate)
    score_current: bool = False           # the folds score the current's rows too (MapTerm.score_current)

    @classmethod
    def make(cls, spec: Spec, x, free_ids, terms=(), data: Data | None = None, formula=None) -> "Problem":
        """Free parameters: those whose owner is in ``free_ids`` ("nominal" and candidate ids). With ``data``,
        the knots the recordings did not visit (:func:`visit_time_s` < VISIT_MIN_S) are anchored to 0; with
        ``formula`` too (the family's formula component the table corrects), those beyond the visited range
        hold the family's total (formula + table) at its value at the last visited knot (:func:`hold_rows`)."""
        free = np.array([k for k, (o, _) in enumerate(spec.params) if o in free_ids], int)
        pos = {int(k): j for j, k in enumerate(free)}
        groups = []
        for t in terms:
            idx = [k for k, (o, _) in enumerate(spec.params) if o == t.id]
            R = t.roughness()
            D = np.zeros((R.shape[0], free.size))
            ridge = np.zeros(free.size)
            anchor = np.zeros(free.size)
            vis = visit_time_s(t, data) if data is not None else None
            for j, k in enumerate(idx):
                D[:, pos[k]] = R[:, j]
                ridge[pos[k]] = 1.0
                if vis is not None and vis[j] < VISIT_MIN_S:
                    anchor[pos[k]] = 1.0
            H, b = np.zeros((0, free.size)), np.zeros(0)
            prof = formula_profile(formula, t) if formula is not None and vis is not None else None
            if prof is not None:
                rows, b, held = hold_rows(vis, prof / t.scale)
                H = np.zeros((rows.shape[0], free.size))
                for j, k in enumerate(idx):
                    H[:, pos[k]] = rows[:, j]
                    if held[j]:
                        anchor[pos[k]] = -1.0          # held, never anchored to 0 (anchor_unidentified neither)
            groups.append((D, ridge, anchor, (H, b)))
        return cls(spec, np.asarray(x, float), free, groups, nameplate_prior(spec, free),
                   any(t.score_current for t in terms))

    def penalty(self, lams) -> np.ndarray:
        """The penalty's matrix sum_g lambda_g (D_g^T D_g + RIDGE diag(table_g) + ANCHOR (diag(unvisited_g) +
        H_g^T H_g)) over the free parameters (H: the rows that hold a table's knots beyond the visited range)."""
        if getattr(self, "_unit_penalties", None) is None:       # each group's matrix at lambda = 1, once
            self._unit_penalties = [D.T @ D + RIDGE * np.diag(ridge) + ANCHOR * (np.diag(anchor > 0) + H.T @ H)
                                    for D, ridge, anchor, (H, _) in self.groups]
        P = np.zeros((self.free.size, self.free.size))
        for lam, G in zip(lams, self._unit_penalties):
            P += lam * G
        if self.prior is not None:
            P += np.diag(self.prior)
        return P

    def holds(self) -> bool:
        """Does a table hold knots at targets made from the family's formula (:func:`hold_rows`)? Then the
        formula's parameters must stay where they were when the targets were made."""
        return any(b.size for _, _, _, (_, b) in self.groups)

    def penalty_rows(self, lams) -> tuple[np.ndarray, np.ndarray]:
        """(S, c) with |S theta - c|^2 = the penalty theta^T P theta - 2 pull^T theta up to a constant, over the
        free parameters: the penalty as rows to append to a least-squares residual (S the symmetric square root
        of P, c its pseudo-inverse applied to the pull)."""
        w, V = np.linalg.eigh(self.penalty(lams))
        w = np.clip(w, 0.0, None)
        S = (V * np.sqrt(w)) @ V.T
        return S, np.linalg.pinv(S, rcond=1e-12) @ self.pull(lams)

    def pull(self, lams) -> np.ndarray:
        """The penalty's linear part: sum_g lambda_g ANCHOR H_g^T b_g (the held knots' targets); the penalty is
        theta^T P theta - 2 pull^T theta + const."""
        q = np.zeros(self.free.size)
        for lam, (_, _, _, (H, b)) in zip(lams, self.groups):
            if b.size:
                q += lam * ANCHOR * (H.T @ b)
        return q


def formula_profile(comp, term: "MapTerm") -> np.ndarray | None:
    """The family formula ``comp``'s contribution on ``term``'s knots, in the table's quantity (a torque, a
    friction level, a torque-constant change over angle), where the formula is a function of the table's angle
    alone; None otherwise. Measured through the kernels: the formula's output over the output of the table with
    1 at every knot, at rest (omega 0, the current 1 A, a bristle fully deflected: its presliding distance, the
    last parameter of every unit-bristle component)."""
    if comp is None or term.cls.grid_field != "angle_rad" or len(term.value_fields) != 1:
        return None
    unit = term.component(np.ones(term.n_coef))
    out = np.zeros(term.grid.size)
    pf, pu = comp.param_vector(), unit.param_vector()
    ds = np.zeros(max(len(comp.state_names), len(unit.state_names), 1))
    for k, phi in enumerate(term.grid):
        f = comp.kernel(0.0, float(phi), 0.0, 1.0, 0.0, np.array([pf[-1]] * ds.size), pf, ds)
        u = unit.kernel(0.0, float(phi), 0.0, 1.0, 0.0, np.array([pu[-1]] * ds.size), pu, ds)
        j = int(np.argmax(np.abs(u[:2])))
        if not np.all(np.isfinite(f)) or abs(u[j]) < 1e-12:
            return None
        out[k] = f[j] / u[j]
    return out


def hold_rows(visit_s: np.ndarray, prof: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows (over one table's knots), targets and the held mask that hold the family's total, formula ``prof`` +
    table, at its value at the first / last visited knot for every knot beyond it (normalized units): a formula
    fitted on part of the stroke is not extrapolated where the recordings did not go (an angle-dependent
    friction's quadratic added 0.13 N m at the open stop, 65 % of the friction, where the data ended 12 deg
    before; docs/diagnosis-history.md, round 14)."""
    n = prof.size
    seen = np.flatnonzero(np.asarray(visit_s[:n]) >= VISIT_MIN_S)
    held = np.zeros(n, bool)
    rows, b = [], []
    if seen.size:
        for k in list(range(0, seen[0])) + list(range(seen[-1] + 1, n)):
            e = seen[0] if k < seen[0] else seen[-1]
            r = np.zeros(n)
            r[k], r[e] = 1.0, -1.0
            rows.append(r)
            b.append(prof[e] - prof[k])
            held[k] = True
    return (np.array(rows).reshape(-1, n), np.array(b), held)


NOMINAL_PRIOR = 0.2      # the calibrated nominal parameters' spread about the nameplate (relative, one sigma)


def nameplate_prior(spec: Spec, free: np.ndarray) -> np.ndarray | None:
    """Per free parameter: the weight 1/sigma^2 (normalized units, residuals in noise units) that pulls a nominal
    parameter (friction level, spring preload and rate) to its nameplate value with sigma = NOMINAL_PRIOR of it.
    Where the data identify the parameter this is negligible; where a table can do its job (a table's straight
    line above limp-home is the spring's preload and rate to the data there) it decides the split."""
    if not NOMINAL_PRIOR:
        return None
    w = np.zeros(free.size)
    for j, k in enumerate(free):
        owner, p = spec.params[k]
        if owner == "nominal" and p.init > 0.0:
            w[j] = (p.scale / (NOMINAL_PRIOR * p.init)) ** 2
    return w


def _row_info(data: Data, current: bool = False):
    """Per residual element (fit.residuals layout, current included): fold (0/1) and whether it is scored by the
    folds (an angle; with ``current`` the current's rows too)."""
    fold, is_angle = [], []
    for k, rd, m, kind in _layout(data, None, True):
        t = rd.rec.t_s
        fold.append((np.floor((t - t[0]) / F.fold_block_s(rd)).astype(int) % 2))   # fit.fold_masks' layout
        is_angle.append(np.full(t.size, kind == "angle" or current))
    return np.concatenate(fold), np.concatenate(is_angle)


def _residual(spec, data, x):
    """The normalized residual (fit.make_fun's, current included); FAIL everywhere if the simulation fails."""
    try:
        plant, sensor = spec.build(np.asarray(x, float))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pred = simulate(plant, sensor, data)
    except (ValueError, FloatingPointError):
        pred = None
    if pred is None:
        return np.full(_row_info(data)[0].size, F.FAIL)
    r = residuals(pred, data)
    r[~np.isfinite(r)] = F.FAIL
    return r


def jacobian(pb: Problem, data: Data, r0: np.ndarray, step: float = FD_STEP) -> np.ndarray:
    """Forward differences of the residual over the free parameters (one simulation each)."""
    J = np.empty((r0.size, pb.free.size))
    lo, hi = pb.spec.bounds()
    for j, k in enumerate(pb.free):
        x = pb.x.copy()
        h = step if x[k] + step <= hi[k] else -step
        x[k] += h
        J[:, j] = (_residual(pb.spec, data, x) - r0) / h
    return J


def _jacobian_at(pb: Problem, data: Data, r: np.ndarray, jac_substeps: int) -> np.ndarray:
    """:func:`jacobian` of ``pb`` at ``jac_substeps`` (:func:`_coarse`); ``r``, the residual at pb.x at the
    model's own step, is reused where that step is not coarsened (one simulation less)."""
    spec = _coarse(pb.spec, jac_substeps)
    r0 = r if spec is pb.spec else _residual(spec, data, pb.x)
    return jacobian(dataclasses.replace(pb, spec=spec), data, r0)


def _penalty_scales(J: np.ndarray, pb: Problem) -> list:
    """Per table: mean squared Jacobian column over mean squared roughness column, so that a relative
    weight of 1 balances the data and the roughness whatever the table's units."""
    out = []
    for D, ridge, _, _ in pb.groups:
        m = ridge > 0
        jj = float(np.mean(np.sum(J[:, m] ** 2, axis=0))) if m.any() else 1.0
        dd = float(np.mean(np.sum(D[:, m] ** 2, axis=0))) if m.any() and D.size else 1.0
        dd = dd if dd > 0.0 else 1.0          # no roughness at all (a direction offset alone): the ridge's scale
        out.append(max(jj, 1e-12) / max(dd, 1e-12))
    return out


def _gram(J, r, rows=None):
    """(J^T J, J^T r, r^T r) over the residual rows ``rows`` (all if None)."""
    if rows is not None:
        J, r = J[rows], r[rows]
    return J.T @ J, J.T @ r, float(r @ r)


def _solve_gram(A, g, pb: Problem, lams, theta=None, damping: float = 0.0):
    """Regularized (Levenberg-damped) Gauss-Newton step from the normal equations of some residual rows."""
    theta = pb.x[pb.free] if theta is None else theta
    s = max(float(np.mean(np.diag(A))), 1e-12)
    P = pb.penalty(lams)
    rhs = -(g + P @ theta - pb.pull(lams))
    A2 = A + P + damping * np.diag(np.diag(A)) + 1e-9 * s * np.eye(A.shape[0])
    try:
        return np.linalg.solve(A2, rhs)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A2, rhs, rcond=None)[0]


def _solve(J, r, pb: Problem, lams, rows=None, theta=None, damping: float = 0.0):
    """Regularized Gauss-Newton step over the free parameters, using residual rows ``rows`` (all if None)."""
    A, g, _ = _gram(J, r, rows)
    return _solve_gram(A, g, pb, lams, theta, damping)


def _clip(pb: Problem, x):
    lo, hi = pb.spec.bounds()
    return np.clip(x, lo + 1e-9, hi - 1e-9)


def _objective(pb: Problem, r: np.ndarray, theta: np.ndarray, lams) -> float:
    return float(r @ r) + float(theta @ pb.penalty(lams) @ theta) - 2.0 * float(pb.pull(lams) @ theta)


class _Folds:
    """Normal equations of each fold (fit) and of the other fold's angle rows (score), computed once."""

    def __init__(self, J, r, data: Data, current: bool = False):
        fold, is_angle = _row_info(data, current)
        self.fit = [_gram(J, r, fold == f)[:2] for f in (0, 1)]
        self.test = [_gram(J, r, (fold != f) & is_angle) for f in (0, 1)]

    def score(self, pb: Problem, lams) -> float:
        """Predicted held-out sum of squares |r_B + J_B d_A|^2 + |r_A + J_A d_B|^2 (linearized)."""
        tot = 0.0
        for (A, g), (At, gt, ct) in zip(self.fit, self.test):
            d = _solve_gram(A, g, pb, lams)
            tot += ct + 2.0 * float(d @ gt) + float(d @ At @ d)
        return tot


def choose_lambdas(J, r, pb: Problem, data: Data, grid=LAMBDAS, sweeps: int = 2) -> tuple[list, list]:
    """Roughness weights (relative) by linearized cross-validation over the two time-block folds, angle rows
    scored, every free parameter (the nominal ones with the tables) solved per fold: a common weight first, then
    each table's weight in turn (coordinate search on the grid)."""
    if not pb.groups:
        return [], []
    folds = _Folds(J, r, data, pb.score_current)
    sc = _penalty_scales(J, pb)
    grid = list(grid)
    absl = lambda rel: [a * b for a, b in zip(rel, sc)]
    curve = [folds.score(pb, absl([g] * len(sc))) for g in grid]
    rel = [grid[int(np.argmin(curve))]] * len(sc)
    if len(sc) > 1:
        for _ in range(sweeps):
            for k in range(len(sc)):
                best = None
                for g in grid:
                    trial = list(rel)
                    trial[k] = g
                    v = folds.score(pb, absl(trial))
                    if best is None or v < best[0]:
                        best = (v, g)
                rel[k] = best[1]
    return rel, curve


@dataclasses.dataclass
class PenalizedFit:
    fit: F.FitResult
    lams: list                    # absolute roughness weights per table
    lams_rel: list                # relative weights (1: data and roughness balanced)
    jac: np.ndarray               # last Jacobian over the free parameters
    problem: Problem
    cv_curve: list


def anchor_unidentified(pb: Problem, J: np.ndarray, share: float = ID_MIN) -> Problem:
    """``pb`` with every table knot whose Jacobian column (``J`` over pb.free) has less than ``share`` of its
    table's median column energy anchored to 0 (in addition to the knots the recordings did not visit)."""
    groups = []
    for D, ridge, anchor, hold in pb.groups:
        cols = np.flatnonzero(ridge > 0)
        new = anchor.copy()
        if cols.size:
            e = np.sum(J[:, cols] ** 2, axis=0)
            med = float(np.median(e))
            if med > 0.0:
                new[cols[(e < share * med) & (anchor[cols] == 0)]] = 1.0
        groups.append((D, ridge, new, hold))
    return dataclasses.replace(pb, groups=groups)


def _coarse(spec: Spec, substeps: int) -> Spec:
    """The same model at a coarser integrator step (for Jacobians only)."""
    if spec.base.substeps <= substeps:
        return spec
    return Spec(spec.base.replace(substeps=substeps), spec.candidates, spec.nominal)


def fit_penalized(pb: Problem, data: Data, grid=LAMBDAS, iters: int | None = None, jac_substeps: int = JAC_SUBSTEPS,
                  log=None) -> PenalizedFit:
    """Output-error fit of the free parameters with the roughness penalty; the weights by cross-validation
    (re-chosen at every Jacobian; the step is damped (Levenberg) if the plain one does not lower the
    penalized objective). Jacobians are taken at
    ``jac_substeps`` (the residual itself at the model's own step)."""
    iters = GN_ITER if iters is None else iters
    x = _clip(pb, pb.x.copy())
    pb = dataclasses.replace(pb, x=x)
    r = _residual(pb.spec, data, x)
    lams = rel = None
    curve = []
    J = None
    for it in range(iters):
        J = _jacobian_at(pb, data, r, jac_substeps)
        if it == 0:
            pb = anchor_unidentified(pb, J)
        rel, c = choose_lambdas(J, r, pb, data, grid)      # re-chosen at every linearization
        curve = curve or c
        lams = [a * b for a, b in zip(rel, _penalty_scales(J, pb))]
        theta = pb.x[pb.free]
        obj0 = _objective(pb, r, theta, lams)
        A, g, _ = _gram(J, r)
        improved = False
        for damping, a in ((0.0, 1.0), (0.0, 0.5), (0.1, 1.0), (1.0, 1.0)):
            d = _solve_gram(A, g, pb, lams, damping=damping)
            xn = pb.x.copy()
            xn[pb.free] = theta + a * d
            xn = _clip(pb, xn)
            rn = _residual(pb.spec, data, xn)
            objn = _objective(pb, rn, xn[pb.free], lams)
            if objn < obj0:
                improved = True
                break
        if not improved:
            break
        gain = (obj0 - objn) / max(obj0, 1e-300)
        pb = dataclasses.replace(pb, x=xn)
        r = rn
        if log:
            log(f"    penalized fit: iteration {it + 1}, objective {obj0:.4g} -> {objn:.4g}")
        if gain < 0.005:
            break
    Jfull = np.zeros((r.size, len(pb.x)))
    Jfull[:, pb.free] = J
    fr = F.FitResult(pb.spec, pb.x, float(r @ r), r.size, Jfull, 0, F.integrated_time(r),
                     F.block_scores(Jfull, r, F.residual_blocks(data, F.BLOCK_S)))
    return PenalizedFit(fr, lams, rel, J, pb, curve)


def heldout_error(pb: Problem, data: Data, lams=(), J=None, jac_substeps: int = JAC_SUBSTEPS) -> float:
    """Held-out mean square of the normalized angle residual: on each fold the free parameters are refitted
    by one regularized Gauss-Newton step from ``pb.x`` (Jacobian ``J``, computed if None), the other fold's
    residual is simulated. Comparable between a formula (no tables) and a map."""
    r = _residual(pb.spec, data, pb.x)
    if J is None:
        J = _jacobian_at(pb, data, r, jac_substeps)
    fold, is_angle = _row_info(data, pb.score_current)
    tot, cnt = 0.0, 0
    for f in (0, 1):
        d = _solve(J, r, pb, list(lams) or [0.0] * len(pb.groups), fold == f)
        x = pb.x.copy()
        x[pb.free] = x[pb.free] + d
        x = _clip(pb, x)
        rn = _residual(pb.spec, data, x)
        test = (fold != f) & is_angle
        tot += float(rn[test] @ rn[test])
        cnt += int(test.sum())
    return tot / max(cnt, 1)


def split_start(spec: Spec, x0: np.ndarray, cid: str, term: MapTerm, data: Data) -> np.ndarray:
    """The start of a :func:`torque_emf_term` fit: the best point of a grid over the torque constant (SPLIT_TORQUE,
    shares of the nameplate's c_M, every nominal torque co-scaled as fit.coscale_point does: the calibration
    balanced the plate's rests with the old constant) and the back-EMF constant (SPLIT_EMF: the formula's delta
    moved, the offset moved back, the torque unchanged), then a local fit from there (SPLIT_NFEV). From the
    formula's optimum the offset alone only raises the residual: the spring and friction levels must follow the
    torque, and the back-EMF the other way (3B s33 closed: Gauss-Newton and a free local fit stayed at offset 0,
    observer cost 6033 / 5953; from the grid's best point 5610, the truth's point 5628). ``x0``: the formula's
    optimum with the term's coefficients (the last) at 0; the grid moves them together (a direction the recordings
    did not drive the current in is pulled back to 0 by the penalized fit's anchoring). Returns x0 where the grid
    finds nothing lower."""
    names = list(spec.values(np.zeros(len(spec.params))))
    k_d, k_c = names.index(f"{cid}.delta_Nm_per_A"), np.arange(len(x0) - term.n_coef, len(x0))
    p_d = spec.params[k_d][1]
    c_m = float(getattr(spec.base.drive.params, "torque_constant_Nm_per_A", 0.0) or 0.0)
    d0 = p_d.init + p_d.scale * float(x0[k_d])
    kt0 = c_m + d0
    if not (c_m > 0.0 and kt0 > 0.0):
        return x0
    lo, hi = spec.bounds()
    fun = F.make_fun(spec, data)
    r0 = fun(x0)
    if fun.failure is not None:
        return x0
    best_c, best_x = float(r0 @ r0), x0
    for s in SPLIT_TORQUE:
        kf = (kt0 + s * c_m) / kt0
        for e in SPLIT_EMF:
            if s == 0.0 and e == 0.0:
                continue
            x = x0.copy()
            x[k_c] = (s - e) * c_m / term.scale
            x[k_d] = x0[k_d] + e * c_m / p_d.scale
            for i, q in enumerate(spec.nominal):
                if q.unit.startswith("N m"):
                    x[i] = ((q.init + q.scale * float(x0[i])) * kf - q.init) / q.scale
            if np.any(x <= lo) or np.any(x >= hi):
                continue
            r = fun(x)
            if fun.failure is None and float(r @ r) < best_c:
                best_c, best_x = float(r @ r), x
    fun.failure = None
    if best_x is x0:
        return x0
    try:
        res = F.local_fit(fun, best_x, lo, hi, 0.03, SPLIT_NFEV)
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        return best_x
    return res.x if 2.0 * float(res.cost) < best_c else best_x


# ------------------------------------------------------------------------------------ refinement of a family
@dataclasses.dataclass
class Refinement:
    family_id: str                # the catalogue candidate whose shape was refined
    term: MapTerm
    fit: F.FitResult              # the model with the map (formula kept, map as a correction)
    lam_rel: float
    heldout_formula: float
    heldout_map: float
    kept: bool
    problem: Problem | None = None  # the table's penalized problem and its chosen absolute roughness weights
    lams: tuple = ()                # (run.polish refits on the continuous replay with the same penalty)

    def table(self) -> dict:
        """The learned table: grid and values (physical units)."""
        vals = self.fit.spec.values(self.fit.x)
        coef = np.array([vals[f"{self.term.id}.c{k}"] for k in range(self.term.n_coef)])
        comp = self.term.component(coef)
        d = comp.params.to_dict()
        return {"component": comp.kind, **{k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}}


def _formula_component(fr: F.FitResult, cid: str):
    """The fitted formula component of candidate ``cid`` in ``fr``'s model (None if it has none)."""
    plant, _ = fr.spec.build(fr.x)
    return next((e for e in plant.effects if getattr(e, "effect_id", None) == cid), None)


def refine_family(final: F.FitResult, cid: str, data: Data, log=print, split: bool = True) -> Refinement | None:
    """Refine accepted candidate ``cid`` of ``final`` by its table (None: no table form for the family); with
    several table forms (:func:`family_terms`) the one with the lowest held-out error. ``split`` False: without
    the torque-constant split (:func:`torque_emf_term`), for refine's test whether the first effect with its table
    replaces the later ones: the split's two extra constants beat torque_constant_error + inductance_saturation on
    the folds (held-out 3.06 against 4.91) and displaced the saturation, twin 1.23x -> 6.05x
    (torque_constant_error@2 3B s20 open, round 27)."""
    terms = [t for t in family_terms(cid, final.spec.base, data) if split or not t.split_start]
    if not terms:
        return None
    pb_formula = Problem.make(final.spec, final.x, ("nominal", cid))
    h_formula = heldout_error(pb_formula, data)
    # the table is fitted, and its roughness chosen, on the fit's view (every replay segment restarted at the
    # readings) and, on an open-loop recording, also on the replay that goes on from the model's own state
    # (model.Data.continuity): over restarted segments a wrong shape costs little, the spring's rate and preload
    # can absorb it, and the cross-validation keeps the formula (docs/diagnosis-history.md, round 13). The fit with the
    # lower held-out error (on the fit's view, as the formula's) is taken.
    views = [data]
    if not data.continuity and any(rd.residual == "replay" for rd in data.recs):
        views.append(dataclasses.replace(data, continuity=True))
    best = None
    comp = _formula_component(final, cid)
    h_cur = None                # the formula's held-out error with the current's rows scored too (once)
    best_score = math.inf
    for term in terms:
        spec_m = final.spec.with_candidate(term.candidate())
        x0 = np.concatenate([final.x, np.zeros(term.n_coef)])
        if term.split_start:
            x0 = split_start(spec_m, x0, cid, term, data)
        pb = Problem.make(spec_m, x0, ("nominal", cid, term.id) if term.split_start else ("nominal", term.id),
                          [term], data, formula=comp)
        h_map, pf = math.inf, None
        # a heating's states persist over the restarted segments (Effect.persistent_states): the fit's view sees
        # its history already, and on the continuous replay the refitted nominal parameters alone passed the
        # folds (coil_heating@1 3B s24 open: the network ~0, kept at held-out 1.03 -> 0.93, the twin 2.31x -> 2.72x)
        for view in (views[:1] if term.score_current or term.split_start else views):
            pf_v = fit_penalized(pb, view, log=None)
            h_v = heldout_error(dataclasses.replace(pf_v.problem, x=pf_v.fit.x), data, pf_v.lams,
                                pf_v.jac if view is data else None)
            if pf is None or h_v < h_map:
                h_map, pf, cont = h_v, pf_v, view is not data
        d_formula, d_map = h_formula, h_map          # the scores that decide
        if term.score_current:
            # a term of the coil's voltage balance (the heating) is scored on the current's rows too: in a closed
            # loop the angle hides it, the current shows it (a two-node heating's one-node fit: held-out angle at
            # the noise, the twin 8.2x on the other loop type; docs/diagnosis-history.md, round 26 o26thermal). The
            # Refinement keeps the angle's held-out errors, which refine compares with other models'.
            if h_cur is None:
                h_cur = heldout_error(dataclasses.replace(pb_formula, score_current=True), data)
            d_formula = h_cur
            d_map = heldout_error(dataclasses.replace(pf.problem, x=pf.fit.x), data, pf.lams, pf.jac)
            h_map = heldout_error(dataclasses.replace(pf.problem, x=pf.fit.x, score_current=False), data, pf.lams,
                                  pf.jac)
        kept = d_map < (1.0 - MIN_GAIN) * d_formula
        log(f"  shape of {cid}: {term.id} over {term.cls.grid_field} ({term.grid.size} knots, {term.n_coef} "
            f"coefficients, roughness weight "
            f"{pf.lams_rel[0]:.2g}{', fitted on the continuous replay' if cont else ''}): held-out "
            f"{'(angle and current) ' if term.score_current else ''}{d_formula:.3g} -> "
            f"{d_map:.3g} ({'kept' if kept else 'not kept'})")
        if d_map < best_score:
            best_score = d_map
            best = Refinement(cid, term, pf.fit, pf.lams_rel[0], h_formula, h_map, kept, pf.problem,
                              tuple(pf.lams))
    return best


def plot_table(ax, term: MapTerm, table: dict, title: str):
    """Draw a learned table on a matplotlib axis (grid in deg, rad/s or A)."""
    g = np.asarray(table[term.cls.grid_field], float)
    x = np.degrees(g) if term.cls.grid_field == "angle_rad" else g
    xl = {"angle_rad": "angle [deg]", "speed_rad_s": "speed |omega| [rad/s]", "current_A": "current [A]",
          "time_constant_s": "branch time constant [s]"}
    if term.cls.grid_field in LOG_GRIDS:
        ax.set_xscale("log")
    for f in term.value_fields:
        ax.plot(x, table[f], marker=".", lw=1.0, label=f)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel(xl.get(term.cls.grid_field, term.cls.grid_field))
    ax.set_ylabel(term.unit)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
