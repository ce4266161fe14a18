"""Shapes from the data: the lookup tables a named family's formula is refined by (docs/diagnosis-shapes.md).

A *map term* (:class:`MapTerm`) is a table component of ``etb_gym.components.effects_maps`` on a knot grid taken
from the plant and the data (the angle knots span the plant's own stops, the speed and current knots the range
the recordings visit); its knot values are the fitted coefficients c. This module holds the terms, their grids and
the time the recordings spent near each knot (:func:`visit_time_s`); the terms are fitted by the penalized
Gauss-Newton of :mod:`.penalized` and kept or not by :func:`.family_table.refine_family`. Speed and current tables
get an extra knot beyond the range the recordings visited (a table is held constant beyond its last knot; the
knot is anchored, :mod:`.penalized`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.interpolate import CubicSpline

from ..components import effects_maps as mx
from .candidates import Candidate, FitParam
from .model import Data

ANGLE_KNOTS = 16         # knots of a refined angle map over the stroke
PROFILE_KNOTS = 17       # knots of a torque-constant profile over the stroke (5.6 deg on 3B)
FRICTION_ANGLE_KNOTS = 33  # at most this many knots of a friction level over the stroke: PROFILE_KNOTS' 17 and one
                           # between each pair where the recordings dwelt (2.8 deg on 3B; friction_angle_grid)
VISIT_MIN_S = 0.02       # a knot the recordings spent less time near (hat-weighted) is not identified by them
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
    coef_grid: np.ndarray | None = None   # where the basis interpolates the coefficients onto a finer grid: the
                                          # coefficients' own knots (roughness and visit time are taken there;
                                          # smooth_current_term)
    coef_axis: np.ndarray | None = None   # ... and those knots' positions on the axis the roughness is taken over
    coef_basis: np.ndarray | None = None  # ... and those knots' values = coef_basis @ coefficients (None: the
                                          # coefficients themselves; an odd table: smooth_current_term(odd=True))
    preferred: bool = False       # where the folds keep it, kept over the family's other forms unless one lowers
                                  # the held-out error by family_table.MIN_GAIN (family_table.choose_form; the odd
                                  # supply-drop table: smooth_current_term)
    second_start: bool = False    # fitted a second time, the first fit's table mean moved into the nominal
                                  # Coulomb level and the table at 0; the folds choose by MIN_GAIN (a friction
                                  # level over angle: family_table._second_start)

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
        if self.coef_grid is not None:           # second differences of the coefficients on their own axis
            if self.coef_basis is None:
                return _second_differences(np.asarray(self.coef_axis, float), 1, self.n_coef)
            M = np.asarray(self.coef_basis, float)
            return _second_differences(np.asarray(self.coef_axis, float), 1, M.shape[0]) @ M
        if self.basis is not None:
            R = dataclasses.replace(self, basis=None).roughness()
            return R @ self.basis if R.size else np.zeros((0, self.n_coef))
        return _second_differences(np.log(self.grid) if self.cls.grid_field in LOG_GRIDS else self.grid,
                                   len(self.value_fields), self.n_coef)

    def candidate(self) -> Candidate:
        fit = tuple(FitParam(f"c{k}", 0.0, -1e3 * self.scale, 1e3 * self.scale, self.scale, self.unit)
                    for k in range(self.n_coef))
        return Candidate(self.id, self.family, self.cls.description, fit, component=_Factory(self))

    def component(self, coef) -> mx.Effect:
        return _Factory(self).make(np.asarray(coef, float))


def _second_differences(x: np.ndarray, n_fields: int, n_coef: int) -> np.ndarray:
    """Rows of divided second differences over the knots ``x`` (possibly non-uniform, scaled to a uniform
    grid's), per value field of ``x.size`` coefficients each."""
    n = x.size
    if n < 3:
        return np.zeros((0, n_coef))
    h = np.diff(x)
    rows = []
    for f in range(n_fields):
        for k in range(1, n - 1):
            r = np.zeros(n_coef)
            a, b = h[k - 1], h[k]
            m = 0.5 * (a + b)
            r[f * n + k - 1] = m / a
            r[f * n + k] = -m / a - m / b
            r[f * n + k + 1] = m / b
            rows.append(r)
    return np.array(rows)


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


def resting_mask(data: Data) -> np.ndarray:
    """Per sample of :func:`data_speeds_rad_s`: True inside the rest runs (``RecData.rest``, the noise floor's runs
    where the plate stands still) of the recordings replayed as open loops (``residual`` "replay": the loop
    detector's choice, or the user's ``--residual``). There the readings' speed is the noise's
    (0.01-0.1 rad/s on a 0.03 deg reading, either sign), not a sliding speed, and a plate resting under the
    recorded voltage lies anywhere inside the friction band: a speed table's knots are not visited by them
    (round 34, x34stribeck: rest credited 0.4-0.9 s to each direction's 0.01-0.1 rad/s knots of stribeck@2
    random open s46, whose sliding spent 0.003-0.016 s there; the table put a -11 mN m closing dip there, which
    pushed the twin on where the plate stops at a set point of the held-out closed loop: 43x, 15x with the rule).
    A closed loop's rest runs stay counted: there the controller holds the plate against the band, its voltage
    working with the reading noise at every set point (0.09 V per sample on stribeck@2 random closed s45, 0.01-0.02
    V on the open loops), which the observer residual sees at those knots (their +0.3-0.8 mN m opening level took
    that twin to 2.18x, 2.99x without them)."""
    out = []
    for rd in data.recs:
        m = np.zeros(rd.rec.n, bool)
        if rd.residual == "replay":
            for a, b in rd.rest:
                m[a:b] = True
        out.append(m)
    return np.concatenate(out)


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


FINE_PER_INTERVAL = 8    # smooth_current_term: exported knots per interval of the coefficients' knots
WARP_CURRENT = NEAR_ZERO[0]   # ... the current axis is warped to log(1 + |i| / i_w), i_w = this share of the
                              # recorded |current|'s 99.8 % quantile


def smooth_current_term(term: MapTerm, data: Data, odd: bool = False) -> MapTerm:
    """``term`` (a table over current, one value field) with the same coefficients, but its exported table a
    cubic spline through them on the warped axis s = sign(i) log(1 + |i| / i_w), tabulated on FINE_PER_INTERVAL
    knots per interval (uniform in s) so the plant's piecewise-linear lookup follows the spline. A semiconductor's
    forward drop grows with the log of the current, a resistance linearly: on the current's own axis such a loss
    bends most near 0 A, and a straight line between knots 0.3-1 A apart is off by 10-50 mV where a 2 mV error
    moves a plate held against its spring by more than the noise (supply_drop@1 random s36 open: the truth's own
    drop tabulated on the 13-knot current grid replays the held-out recording at 8.0x the noise, the same 13 values
    splined on the warped axis at 1.1x; docs/diagnosis-history.md, round 30 e30supply). Roughness: the coefficients'
    second differences over s; visit time: at the coefficients' knots.

    ``odd``: the table odd in the current, d(-i) = -d(i): one coefficient per knot of the side the recordings
    reach further (``term``'s knots there), mirrored onto the other side, 0 at 0 A (:func:`odd_knots`). A supply's
    internal resistance and an H-bridge's drop do not depend on the current's direction (either direction
    conducts through one high-side and one low-side switch of the same kind), so the side an open loop drives
    less (a brief braking current) takes its drop from the side it drives more, where the free table leaves the
    unidentified knots to the formula alone (supply_drop@1 3B s42 open: the negative knots at -1.3..-0.19 A
    anchored, the formula's knee there 10-11 mV short of the truth's drop at -0.2..-0.5 A, where the closed
    held-out recording brakes the plate: all of the twin's 1.58x; docs/diagnosis-history.md, round 33 o33supply).
    The odd table is the family's preferred form: where the folds keep it, a free one (linear or smooth,
    :func:`family_terms`) replaces it only where that lowers the folds' held-out error by MIN_GAIN too
    (family_table.choose_form)."""
    g = np.asarray(term.grid, float)
    M = None
    if odd:
        g, M = odd_knots(g)
    cur = [rd.rec.current_A for rd in data.recs if rd.rec.current_A is not None]
    top = max(float(np.quantile(np.abs(np.concatenate(cur)), 0.998)), 0.1) if cur else max(abs(g[0]), abs(g[-1]))
    iw = WARP_CURRENT * top
    s = np.sign(g) * np.log1p(np.abs(g) / iw)
    fine_s = np.unique(np.concatenate([np.linspace(a, b, FINE_PER_INTERVAL + 1) for a, b in zip(s[:-1], s[1:])]))
    fine = np.sign(fine_s) * iw * np.expm1(np.abs(fine_s))
    fine[np.searchsorted(fine_s, s)] = g                 # the coefficients' knots exactly
    B = CubicSpline(s, np.eye(g.size), bc_type="natural")(fine_s)
    B[np.abs(B) < 1e-12] = 0.0
    if M is not None:
        B = B @ M
    return dataclasses.replace(term, id=f"{term.id}_{'odd' if odd else 'smooth'}", grid=fine, basis=B, coef_grid=g,
                               coef_axis=s, coef_basis=M, preferred=odd)


def odd_knots(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A signed current grid ``g`` made odd: the knots P of the side that reaches further (ties: the positive),
    as -P, 0, P, and the matrix M (knots x P) with the knots' values = M @ (the values at P): +1 at P, -1 at the
    mirrored knot, 0 at 0 A."""
    g = np.asarray(g, float)
    pos, neg = g[g > 0.0], -g[g < 0.0][::-1]
    P = pos if pos.size and (not neg.size or pos[-1] >= neg[-1]) else neg
    n = P.size
    G = np.concatenate([-P[::-1], [0.0], P])
    M = np.zeros((2 * n + 1, n))
    M[n + 1:, :] = np.eye(n)
    M[:n, :] = -np.eye(n)[::-1]
    return G, M


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
    if term.coef_grid is not None:
        v = visit_time_s(dataclasses.replace(term, grid=np.asarray(term.coef_grid, float), basis=None,
                                             coef_grid=None, coef_axis=None, coef_basis=None), data)
        if v is None or term.coef_basis is None:
            return v
        return (np.abs(np.asarray(term.coef_basis)) > 0).T.astype(float) @ v    # an odd table: both signs' time
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
        sliding = ~resting_mask(data)      # the rest runs' readings move by the noise alone: no speed is visited
        out = []
        for f in term.value_fields:
            sel = w > 0 if "opening" in f else (w < 0 if "closing" in f else np.ones(w.size, bool))
            out.append(_hat_time(np.abs(w[sel & sliding]), term.grid, float(np.mean(dts))))
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
    if cid == "supply_drop" and t is not None:      # the same coefficients, splined on a log-warped current axis,
        out.append(smooth_current_term(t, data))    # free on both sides and odd in the current
        out.append(smooth_current_term(t, data, odd=True))
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
                       ("level_Nm",), 0.005, "N m", (("presliding_rad", 2e-3),), second_start=True)
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
