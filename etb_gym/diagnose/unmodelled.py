"""Physics outside the catalogue: the missing torque (or voltage) as a function of the state (docs/diagnosis-shapes.md).

When the candidates leave a significant residual, the calibrated nominal model is extended by a generic set of
regularized tables (``etb_gym.components.effects_maps``) and fitted by output error (penalized.fit_penalized,
roughness weights per table by cross-validation over the time-block folds):

    T(phi)         torque over angle, fine knots over the plant's stroke (resolves a periodic detent torque)
    g(omega)       friction level over speed, per direction (a unit bristle: -g(omega) sign(omega) in sliding)
    dk(phi) i      a torque proportional to current (and its back-EMF), over angle
    u(i)           a voltage drop over current in the coil loop

The fitted tables are then described: which of them matters (the recording's RMS residual when that table is
removed again), whether T(phi) is periodic in angle (a periodogram with harmonics over trial periods, on the
angles the recordings visit: period, amplitude, waveform), how the friction depends on speed and direction,
how strongly the torque follows current. The description, the tables and a plot go to the report under the
ids ``unmodelled_torque`` / ``unmodelled_voltage`` with the words "outside the catalogue".
A periodic angle table is then kept in the twin as a Fourier series (:mod:`.outside_series`).

Decision (:func:`compare`): the generic model replaces the catalogue's explanation when its held-out error
(penalized.heldout_error, same folds and refit rule as the catalogue model's) is lower by GAIN_OUT, or when its
angle table is periodic (no catalogue family acts periodically in angle) and at least as good; then no catalogue
effect is reported as the explanation, unless a catalogue family of the dominant table does the same job with its
own table (:func:`catalogue_alternative`). In a closed loop (``persistent``) a table also matters when removing it
brings back a persistent structure it accounts for (the loop holds the angle's RMS).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..components import effects_maps as mx
from . import fit as F
from .model import Data, Spec, angle_residuals_deg, open_loop, simulate
from .penalized import Problem, fit_penalized, heldout_error
from .shapes import MapTerm, angle_grid, current_grid, speed_grid

GAIN_OUT = 0.10          # held-out error the generic model must win over the catalogue's
RMS_GAIN = 0.10          # ... and over the nominal model, as the catalogue effects must (explain.RMS_MIN_GAIN)
ANGLE_KNOTS = 73         # 1.25 deg over a 90 deg stroke
PERIODS_DEG = (6.0, 60.0)  # trial periods of the periodogram
PERIODIC_R2 = 0.6        # share of the detrended table the periodic fit must explain
MIN_CYCLES = 2.5         # ... over at least this many periods of the visited range
HARMONICS = 3
GN_ITER = 6              # Gauss-Newton iterations of the generic fit (stops earlier when the gain is < 0.5 %)
IMPORTANCE_SHARE = 0.3  # a table matters if removing it costs this share of what the dominant one costs


CURRENT_COARSE_ANGLE_KNOTS = 9   # the angle table's knots when the current table takes the fine grid


def generic_terms(base, data: Data, voltage: bool = True, current_fine: bool = False) -> list[MapTerm]:
    """The generic tables. ``current_fine``: the torque proportional to current gets the fine angle grid (a
    ripple periodic in angle that scales with the current) and the current-free torque a coarse one."""
    na, nc = (CURRENT_COARSE_ANGLE_KNOTS, ANGLE_KNOTS) if current_fine else (ANGLE_KNOTS, 5)
    terms = [MapTerm("unmodelled_angle", "unmodelled", mx.AngleTorqueMap, angle_grid(base, data, na), ("torque_Nm",),
                     0.005, "N m"),
             MapTerm("unmodelled_speed", "unmodelled", mx.SpeedFrictionMap, speed_grid(data, 6),
                     ("opening_Nm", "closing_Nm"), 0.005, "N m", (("presliding_rad", 2e-3),)),
             MapTerm("unmodelled_current", "unmodelled", mx.TorqueConstantMap, angle_grid(base, data, nc),
                     ("delta_Nm_per_A",), 0.002, "N m/A")]
    if voltage:
        terms.append(MapTerm("unmodelled_voltage", "unmodelled", mx.CurrentVoltageMap, current_grid(data, base, 7),
                             ("drop_V",), 0.02, "V"))
    return terms


@dataclasses.dataclass
class Generic:
    fit: F.FitResult
    terms: list
    lams_rel: list
    heldout: float
    tables: dict                  # term id -> component (the fitted table)
    importance: dict              # term id -> RMS angle residual [deg] with that table removed
    rms_deg: float                # RMS angle residual of the generic model [deg]
    shape: dict                   # the description (see describe)
    z: float | None = None        # a closed loop: the persistent structure's z the generic model leaves
    importance_z: dict = dataclasses.field(default_factory=dict)   # term id -> that z with the table removed
    series: object = None         # a Series that replaced the tables in the twin (with_series), or None
    heldout_tables: float | None = None   # then: the tables' held-out error

    @property
    def id(self) -> str:
        t = max(self.importance, key=self.importance.get) if self.importance else "unmodelled_angle"
        return "unmodelled_voltage" if t == "unmodelled_voltage" else "unmodelled_torque"


def fit_generic(nominal: F.FitResult, data: Data, log=print, current_fine: bool = False,
                persistent=None) -> Generic:
    """The calibrated nominal model plus the generic tables, fitted by penalized output error
    (``current_fine``: see :func:`generic_terms`). ``persistent`` (FitResult -> z of a closed loop's persistent
    structure, disturbance.py): which table matters is also judged by the structure that comes back when it is
    removed (the loop holds the angle, so removing a table barely moves the angle's RMS)."""
    base_spec = Spec(nominal.spec.base, (), nominal.spec.nominal)
    x_nom = np.asarray(nominal.x, float)[:len(base_spec.params)]
    terms, spec, pb, pf = _fit_tables(base_spec, x_nom, data, current_fine)
    if not np.any(pf.fit.x[x_nom.size:]):        # output error took no step: start from the equation error
        rss0 = pf.fit.rss
        for fine in (current_fine,) if current_fine else (False, True):
            seeded = _fit_tables(base_spec, x_nom, data, fine, seed=True)
            if seeded is None:
                continue
            log(f"  outside the catalogue: output error took no step from the nominal model (RSS {rss0:.4g}); "
                f"from the equation error's start ({'fine' if fine else 'coarse'} current table) RSS "
                f"{seeded[3].fit.rss:.4g}" + (" (kept)" if seeded[3].fit.rss < pf.fit.rss else " (not kept)"))
            if seeded[3].fit.rss < pf.fit.rss:
                terms, spec, pb, pf = seeded
    pbf = dataclasses.replace(pf.problem, x=pf.fit.x)
    h = heldout_error(pbf, data, pf.lams, pf.jac)
    vals = spec.values(pf.fit.x)
    tables = {t.id: t.component(np.array([vals[f"{t.id}.c{k}"] for k in range(t.n_coef)])) for t in terms}
    rms = _rms_deg(spec, pf.fit.x, data)
    imp, imp_z = {}, {}
    z = persistent(pf.fit) if persistent is not None else None
    for t in terms:                                   # the RMS residual with this table removed again
        x = pf.fit.x.copy()
        for k, (o, _) in enumerate(spec.params):
            if o == t.id:
                x[k] = 0.0
        imp[t.id] = _rms_deg(spec, x, data)
        if z is not None:
            imp_z[t.id] = persistent(dataclasses.replace(pf.fit, x=x))
    g = Generic(pf.fit, terms, pf.lams_rel, h, tables, imp, rms, {}, z, imp_z)
    g.shape = describe(g, data)
    a = g.shape["angle"]
    log(f"  outside the catalogue: generic tables, held-out {h:.3g}, RMS {rms:.4f} deg"
        + (f", persistent z {z:.1f} (without each table: " + ", ".join(f"{k[11:]} {v:.1f}" for k, v in imp_z.items())
           + ")" if z is not None else "")
        + f"; angle table's best period {a['period_deg'] or 0:.1f} deg, R2 {a['periodic_r2']:.2f}; {g.shape['summary']}")
    return g


EQ_WINDOW_S = 0.021     # the smoothing window of the angle's derivatives (Savitzky-Golay, cubic)
EQ_MOVING_RAD_S = 0.5   # samples moving faster than this (friction is then a level, not a bristle's state)
EQ_STOP_MARGIN_RAD = math.radians(1.0)   # ... and this far from the stops
EQ_ROUGHNESS = 1e-3     # the second differences' weight, relative to the table's mean Gram diagonal


def _hats(x: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The piecewise-linear interpolation's basis (effects_maps.table_lookup, clamped) at ``x``."""
    B = np.zeros((x.size, grid.size))
    xc = np.clip(x, grid[0], grid[-1])
    k = np.clip(np.searchsorted(grid, xc, side="right") - 1, 0, grid.size - 2)
    f = (xc - grid[k]) / (grid[k + 1] - grid[k])
    rows = np.arange(x.size)
    B[rows, k] = 1.0 - f
    B[rows, k + 1] = f
    return B


def _stateless_torque(plant, phi, om, cur) -> np.ndarray:
    """The summed torque of the plant's stateless components (drive, spring, stops, ...) at given states."""
    from ..jit import py_func
    out = np.zeros(phi.size)
    for c in plant.components:
        if c.state_names or getattr(c, "carry", None) is not None:
            continue
        kern, p, s = py_func(c.kernel), np.asarray(c.param_vector(), float), np.zeros(0)
        out += [kern(0.0, float(a), float(b), float(i), 0.0, s, p, s)[0] for a, b, i in zip(phi, om, cur)]
    return out


def equation_error_seed(base_spec: Spec, x_nom: np.ndarray, terms: list, data: Data) -> np.ndarray | None:
    """A start for the nominal parameters and the generic tables by equation error (normalized x of the Spec
    with the tables): on the moving samples, the torque balance J phi'' = sum of the stateless components'
    torques (drive, spring, stops) at the measured angle, its smoothed derivative and the measured current,
    plus the friction (a Coulomb and a viscous level: its bristle state is not measured), plus the tables
    (the angle table's basis, the current table's basis times the current), linearized in the nominal
    parameters (finite differences of those torques), solved by least squares with a roughness penalty on the
    tables. For a replay that drifts far from the recording from the first step, where output error's
    linearization does not reach (issue #15: a current ripple 770x the noise). None when no recording has a
    measured current or too few moving samples."""
    from scipy.signal import savgol_filter
    names = [t.id for t in terms]
    if "unmodelled_angle" not in names or "unmodelled_current" not in names:
        return None
    ta, tc = terms[names.index("unmodelled_angle")], terms[names.index("unmodelled_current")]
    lo, hi = float(ta.grid[0]), float(ta.grid[-1])
    n_nom = x_nom.size
    plants = [base_spec.build(x_nom)[0]]
    for j in range(n_nom):                       # one normalized unit up, each nominal parameter
        x = x_nom.copy()
        x[j] += 1.0
        try:
            plants.append(base_spec.build(x)[0])
        except ValueError:
            plants.append(plants[0])
    rows, rhs = [], []
    for rd in data.recs:
        rec = rd.rec
        if rec.current_A is None:
            continue
        dt = float(rec.dt_s)
        w = max(5, int(round(EQ_WINDOW_S / dt)) | 1)
        if rec.angle_deg.size < 3 * w:
            continue
        phi_m = np.radians(np.asarray(rec.angle_deg, float))
        phi = savgol_filter(phi_m, w, 3)
        om = savgol_filter(phi_m, w, 3, deriv=1, delta=dt)
        acc = savgol_filter(phi_m, w, 3, deriv=2, delta=dt)
        cur = savgol_filter(np.asarray(rec.current_A, float), w, 3)
        m = (np.abs(om) > EQ_MOVING_RAD_S) & (phi > lo + EQ_STOP_MARGIN_RAD) & (phi < hi - EQ_STOP_MARGIN_RAD)
        m[:w] = m[-w:] = False
        k = np.flatnonzero(m)
        if k.size == 0:
            continue
        t0 = _stateless_torque(plants[0], phi[k], om[k], cur[k])
        dT = [_stateless_torque(pl, phi[k], om[k], cur[k]) - t0 if pl is not plants[0] else np.zeros(k.size)
              for pl in plants[1:]]
        inertia = float(plants[0].P[0])
        rhs.append(inertia * acc[k] - t0)
        rows.append(np.concatenate([np.stack(dT, axis=1) if dT else np.zeros((k.size, 0)),
                                    np.stack([np.sign(om[k]), om[k]], axis=1),
                                    _hats(phi[k], np.asarray(ta.grid, float)) * ta.scale,
                                    _hats(phi[k], np.asarray(tc.grid, float)) * (cur[k, None] * tc.scale)], axis=1))
    if not rhs:
        return None
    A, y = np.concatenate(rows), np.concatenate(rhs)
    na, nc = len(ta.grid), len(tc.grid)
    if y.size < A.shape[1]:
        return None
    G = A.T @ A
    d = np.diag(G)
    P = np.diag(1e-6 * max(float(np.mean(d)), 1e-300) + np.zeros(d.size))
    for off, n in ((n_nom + 2, na), (n_nom + 2 + na, nc)):
        D = np.diff(np.eye(n), 2, axis=0)
        sl = slice(off, off + n)
        P[sl, sl] += EQ_ROUGHNESS * float(np.mean(d[sl])) * n * (D.T @ D)
    try:
        b = np.linalg.solve(G + P, A.T @ y)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(b)):
        return None
    vals = {"unmodelled_angle": b[n_nom + 2:n_nom + 2 + na], "unmodelled_current": b[n_nom + 2 + na:]}
    x = np.concatenate([x_nom + b[:n_nom]] + [vals.get(t.id, np.zeros(t.n_coef)) for t in terms])
    spec = base_spec
    for t in terms:
        spec = spec.with_candidate(t.candidate())
    lo_b, hi_b = spec.bounds()
    return np.clip(x, lo_b, hi_b)


def _fit_tables(base_spec: Spec, x_nom: np.ndarray, data: Data, current_fine: bool, seed: bool = False):
    """(terms, spec, problem, penalized fit) of the nominal model plus the generic tables, fitted by output
    error from the nominal model with the tables at zero, or (``seed``) from :func:`equation_error_seed`
    (None when it has none)."""
    terms = generic_terms(base_spec.base, data, current_fine=current_fine)
    spec = base_spec
    for t in terms:
        spec = spec.with_candidate(t.candidate())
    x0 = np.concatenate([x_nom, np.zeros(sum(t.n_coef for t in terms))])
    if seed:
        x0 = equation_error_seed(base_spec, x_nom, terms, data)
        if x0 is None:
            return None
    pb = Problem.make(spec, x0, ("nominal",) + tuple(t.id for t in terms), terms, data)
    return terms, spec, pb, fit_penalized(pb, data, iters=GN_ITER)


def _rms_deg(spec: Spec, x, data: Data) -> float:
    pred = simulate(*spec.build(x), data)
    if pred is None:
        return math.inf
    r = np.concatenate(angle_residuals_deg(pred, data))
    r = r[np.isfinite(r)]
    return float(math.sqrt(np.mean(r ** 2))) if r.size else math.inf


# ------------------------------------------------------------------------------------ describing a table
def periodicity(angle_deg: np.ndarray, value: np.ndarray, weight: np.ndarray | None = None,
                periods_deg=PERIODS_DEG, harmonics: int = HARMONICS, knot_deg: float = 0.0) -> dict:
    """Is ``value`` over ``angle_deg`` periodic? Least squares on [quadratic trend, harmonics 1..H of 1/P]
    over a fine grid of trial periods P, refined around the best; R2 = share of the detrended variance the
    harmonics explain. Returns period_deg, amplitude (half peak-to-peak of the periodic part), r2, cycles,
    harmonic_share (energy beyond the fundamental) and periodic (R2 >= PERIODIC_R2 over >= MIN_CYCLES).
    ``knot_deg``: the values are a table's knots, each standing for the angles within half a spacing of it,
    so the range they cover (for the cycles and the longest trial period) is one spacing wider than the
    first-to-last knot distance."""
    a = np.asarray(angle_deg, float)
    v = np.asarray(value, float)
    w = np.ones_like(a) if weight is None else np.asarray(weight, float)
    sw = np.sqrt(w)
    span = float(a.max() - a.min()) if a.size else 0.0
    cover = span + knot_deg if span > 0 else 0.0
    c = (a - a.mean()) / max(span, 1e-9)
    T = np.stack([np.ones_like(a), c, c ** 2], axis=1)
    coef, *_ = np.linalg.lstsq(T * sw[:, None], v * sw, rcond=None)
    det = v - T @ coef
    var = float(np.sum(w * det ** 2))
    out = {"period_deg": None, "amplitude": 0.0, "r2": 0.0, "cycles": 0.0, "harmonic_share": 0.0,
           "periodic": False}
    tot = float(np.sum(w * (v - np.average(v, weights=w)) ** 2))
    if var <= 1e-6 * tot or var <= 0 or span <= 0:       # nothing left beyond a smooth trend
        return out

    def fit(P):
        cols = [T]
        for h in range(1, harmonics + 1):
            ph = 2 * math.pi * h * a / P
            cols.append(np.stack([np.cos(ph), np.sin(ph)], axis=1))
        X = np.concatenate(cols, axis=1)
        b, *_ = np.linalg.lstsq(X * sw[:, None], v * sw, rcond=None)
        e = v - X @ b
        return 1.0 - float(np.sum(w * e ** 2)) / var, b

    lo, hi = periods_deg[0], min(periods_deg[1], cover)
    if hi <= lo:
        return out
    Ps = np.geomspace(lo, hi, 400)
    r2 = np.array([fit(P)[0] for P in Ps])
    # the shortest period within 2 % of the best R2: a multiple of the period fits as well as the period
    best = float(np.max(r2))
    k = int(np.flatnonzero(r2 >= best - 0.02)[0]) if best > 0 else int(np.argmax(r2))
    k = int(np.argmax(np.where(np.abs(np.arange(r2.size) - k) <= 8, r2, -np.inf)))
    fine = np.linspace(Ps[max(k - 1, 0)], Ps[min(k + 1, Ps.size - 1)], 41)
    rf = [fit(P)[0] for P in fine]
    P = float(fine[int(np.argmax(rf))])
    r2b, b = fit(P)
    amp_h = [math.hypot(b[3 + 2 * h], b[4 + 2 * h]) for h in range(harmonics)]
    # a multiple of the period whose h-th harmonic carries the waveform (a 60 deg fit of a 20 deg square wave,
    # its 3rd harmonic the fundamental, the others fitting the trend): the period is P/h if that fits nearly as well
    h_dom = int(np.argmax(amp_h)) + 1
    while h_dom > 1 and P / h_dom >= lo:
        fine = np.linspace(0.97 * P / h_dom, 1.03 * P / h_dom, 41)
        rf = [fit(Q)[0] for Q in fine]
        Q = float(fine[int(np.argmax(rf))])
        r2q, bq = fit(Q)
        if r2q < max(0.85 * r2b, PERIODIC_R2):
            break
        P, r2b, b = Q, r2q, bq
        amp_h = [math.hypot(b[3 + 2 * h], b[4 + 2 * h]) for h in range(harmonics)]
        h_dom = int(np.argmax(amp_h)) + 1
    ph = [2 * math.pi * (h + 1) * a / P for h in range(harmonics)]
    per = sum(b[3 + 2 * h] * np.cos(ph[h]) + b[4 + 2 * h] * np.sin(ph[h]) for h in range(harmonics))
    e = np.array(amp_h) ** 2
    out.update(period_deg=P, amplitude=0.5 * float(np.max(per) - np.min(per)), r2=float(r2b), cycles=cover / P,
               harmonic_share=float(e[1:].sum() / max(e.sum(), 1e-300)),
               periodic=bool(r2b >= PERIODIC_R2 and cover / P >= MIN_CYCLES))
    return out


def _spacing(grid_deg: np.ndarray) -> float:
    return float(np.median(np.diff(grid_deg))) if len(grid_deg) > 1 else 0.0


def resolvable(grid_deg: np.ndarray) -> tuple:
    """The trial periods a table on ``grid_deg`` can show: at least 4 knots per period (a coarse table's
    wiggles are not a period)."""
    step = float(np.max(np.diff(grid_deg))) if len(grid_deg) > 1 else PERIODS_DEG[1]
    return (max(PERIODS_DEG[0], 4.0 * step), PERIODS_DEG[1])


def _visited(grid_rad: np.ndarray, data: Data) -> np.ndarray:
    """Samples near each knot (the table is only identified where the recordings went)."""
    phi = np.radians(np.concatenate([rd.rec.angle_deg for rd in data.recs]))
    edges = np.concatenate([[-np.inf], 0.5 * (grid_rad[1:] + grid_rad[:-1]), [np.inf]])
    return np.histogram(phi, edges)[0].astype(float)


def identified(grid_rad: np.ndarray, data: Data, limp_home_rad: float = math.nan) -> np.ndarray:
    """Knots whose table value the recordings identify: visited (>= 5 samples near them), not an end knot and
    not a knot whose interval reaches limp-home. The stroke's tables end on the stops (``shapes.angle_grid``),
    where the stop's contact force balances whatever the table holds while the plate rests there: an end
    knot's value is not the torque's (a detent's table read at its closed-stop knot +0.013 N m, the largest of
    the table, and hid its period; round 11). The limp-home spring's contact band does the same where the
    plate rests at limp-home (a closed loop's detent table read -0.015 N m on the knot 0.2 deg from it, three
    times the detent's amplitude, and hid its period; round 12)."""
    vis = _visited(grid_rad, data)
    m = vis >= 5
    m[[0, -1]] = False
    g = np.asarray(grid_rad, float)
    if math.isfinite(limp_home_rad) and g.size > 1:
        k = int(np.searchsorted(g, limp_home_rad))
        for j in (k - 1, k):                          # the knots on either side of limp-home
            if 0 <= j < g.size:
                m[j] = False
    return m


def describe(g: Generic, data: Data) -> dict:
    """Words and numbers for the generic tables: which matter, periodic or not, speed, direction, current."""
    base_rms = g.rms_deg
    top = max(g.importance.values()) - base_rms if g.importance else 0.0
    sig = {k: v for k, v in g.importance.items()
           if v - base_rms > max(0.5 * data.noise_deg, IMPORTANCE_SHARE * top)}
    sig_z = {}
    if g.importance_z and g.z is not None:          # a closed loop: the structure that comes back without a table
        from .disturbance import Z_DETECT, resolved
        top_z = max(g.importance_z.values()) - g.z
        sig_z = {k: v - g.z for k, v in g.importance_z.items()   # the table accounts for a significant structure
                 if v > Z_DETECT and resolved(v, g.z) and v - g.z > IMPORTANCE_SHARE * top_z}
    words = []
    shape = {"terms": {}}
    ta = g.tables["unmodelled_angle"]
    grid = np.asarray(ta.params.angle_rad)
    vis = _visited(grid, data)
    lh = g.fit.spec.base.limp_home_rad if g.fit is not None else math.nan
    m = identified(grid, data, lh)
    adeg = np.degrees(grid)
    tq = np.asarray(ta.params.torque_Nm)
    per = periodicity(adeg[m], tq[m], np.minimum(vis[m], 200.0), resolvable(adeg), knot_deg=_spacing(adeg)) \
        if m.sum() >= 8 else \
        {"periodic": False, "period_deg": None, "amplitude": 0.0, "r2": 0.0, "cycles": 0.0, "harmonic_share": 0.0}
    shape["angle"] = {"periodic": per["periodic"], "period_deg": per["period_deg"], "amplitude_Nm": per["amplitude"],
                      "periodic_r2": per["r2"], "cycles": per["cycles"], "harmonic_share": per["harmonic_share"],
                      "visited_deg": [float(adeg[m].min()), float(adeg[m].max())] if m.any() else None}
    order = sorted(sig, key=lambda k: -sig[k]) + sorted((k for k in sig_z if k not in sig), key=lambda k: -sig_z[k])
    for k in order:
        if k == "unmodelled_angle":
            if per["periodic"]:
                wave = "close to a sine" if per["harmonic_share"] < 0.1 else "not a sine (harmonics hold " \
                    f"{per['harmonic_share']:.0%} of its energy)"
                words.append(f"a torque periodic in angle: period {per['period_deg']:.1f} deg, amplitude "
                             f"{per['amplitude']:.3g} N m, waveform {wave}")
            else:
                j = int(np.argmax(np.abs(tq[m]))) if m.any() else 0
                words.append(f"a torque over angle that is not periodic: largest {tq[m][j]:+.3g} N m at "
                             f"{adeg[m][j]:.0f} deg" if m.any() else "a torque over angle")
        elif k == "unmodelled_speed":
            ts = g.tables[k]
            up, dn = np.asarray(ts.params.opening_Nm), np.asarray(ts.params.closing_Nm)
            sp = np.asarray(ts.params.speed_rad_s)
            asym = float(np.max(np.abs(up - dn))) / max(float(np.max(np.abs(np.concatenate([up, dn])))), 1e-12)
            trend = "rising" if up[-1] + dn[-1] > up[0] + dn[0] else "falling"
            words.append(f"a friction torque against the motion that depends on speed ({trend} from "
                         f"{0.5 * (up[0] + dn[0]):+.3g} N m at rest to {0.5 * (up[-1] + dn[-1]):+.3g} N m at "
                         f"{sp[-1]:.3g} rad/s)" + ("; it differs by direction" if asym > 0.3 else
                                                   "; the same in both directions"))
            shape["speed"] = {"direction_dependent": bool(asym > 0.3), "trend": trend}
        elif k == "unmodelled_current":
            tc = g.tables[k]
            dk = np.asarray(tc.params.delta_Nm_per_A)
            cg = np.asarray(tc.params.angle_rad)
            cper = {"periodic": False}
            if cg.size >= 20:                           # fine grid: is the current's torque periodic in angle?
                cv = _visited(cg, data)
                cm = identified(cg, data, lh)
                if cm.sum() >= 8:
                    # (by first-to-last knot: with the knots' coverage a 3 s open-loop detent's current table
                    # passed at 2.5 periods and the current-scaled fit, 5 % lower held-out, called it a ripple)
                    cper = periodicity(np.degrees(cg[cm]), dk[cm], np.minimum(cv[cm], 200.0),
                                       resolvable(np.degrees(cg)))
            if cper["periodic"]:
                words.append(f"a torque proportional to the current and periodic in angle: period "
                             f"{cper['period_deg']:.1f} deg, amplitude {cper['amplitude']:.3g} N m/A")
            else:
                words.append(f"a torque proportional to current, {dk.min():+.3g} to {dk.max():+.3g} N m/A over the stroke")
            shape["current"] = {"periodic": bool(cper["periodic"]), "period_deg": cper.get("period_deg"),
                                "amplitude_Nm_per_A": cper.get("amplitude", 0.0)}
        elif k == "unmodelled_voltage":
            tv = g.tables[k]
            ci, dv = np.asarray(tv.params.current_A), np.asarray(tv.params.drop_V)
            words.append(f"a voltage drop over current in the coil loop, {dv[0]:+.3g} V at {ci[0]:.2g} A to "
                         f"{dv[-1]:+.3g} V at {ci[-1]:.2g} A")
        shape["terms"][k] = {"rms_without_deg": g.importance[k]}
        if k in g.importance_z:
            shape["terms"][k]["z_without"] = g.importance_z[k]
    if not words:
        words.append("no single table dominates; the mismatch is spread over angle, speed and current")
    shape["summary"] = "outside the catalogue: " + "; ".join(words)
    shape["significant_terms"] = order
    return shape


# ------------------------------------------------------------------------------------ the decision
def compare(generic: Generic, heldout_catalogue: float, rms_nominal_deg: float, data: Data,
            ps: dict | None = None) -> bool:
    """True when the generic tables explain the residual better than the catalogue model (held-out error
    lower by GAIN_OUT, or periodic in angle, the period established (:func:`period_established`, ``ps``: the
    residual's periodic structure), and no worse) and lower the nominal model's RMS by RMS_GAIN."""
    if not generic.importance or not math.isfinite(generic.rms_deg):
        return False
    if generic.rms_deg > (1.0 - RMS_GAIN) * rms_nominal_deg:
        return False
    better = generic.heldout < (1.0 - GAIN_OUT) * heldout_catalogue
    periodic = (periodic_term(generic.shape) is not None and generic.heldout <= 1.02 * heldout_catalogue
                and period_established(generic, ps, data))
    return bool(better or periodic)


def visited_span_deg(data: Data) -> float:
    """The span of the angles the recordings' readings visit [deg]."""
    a = np.concatenate([np.asarray(rd.rec.angle_deg, float) for rd in data.recs]) if data.recs else np.zeros(0)
    a = a[np.isfinite(a)]
    return float(a.max() - a.min()) if a.size else 0.0


def period_established(g: Generic, ps: dict | None, data: Data, log=None) -> bool:
    """Is the period in angle of the outside description ``g`` established, so that it may decide against an
    equally good catalogue model: seen over MIN_CYCLES of the angles the recordings visit (as the tables'
    periodogram requires), or the period (or a multiple, 2 or 3 times: HARMONIC_TOL) of the significant periodic
    structure ``ps`` the catalogue model leaves (:func:`residual_period`), a second estimate of it? Why: a Fourier
    series started from a table's periodogram that fell short of MIN_CYCLES fits any smooth torque over a span of
    1-2 of its periods (airflow_torque@1 random closed s37, a logistic plateau over 6-65 deg: a 38.4 deg series,
    1.5 cycles, the residual's structure 14.8 deg, held-out 1.01 against 1.07 for the airflow formula, which the
    observer left at 0.95 noise floors; the airflow was dropped for "outside the catalogue", twin 54x)."""
    d = periodic_term(g.shape)
    if d is None or not d.get("period_deg"):
        return False
    P = float(d["period_deg"])
    cycles = visited_span_deg(data) / P if P > 0 else 0.0
    if cycles >= MIN_CYCLES:
        return True
    if ps is not None and ps.get("significant") and ps.get("period_deg"):
        r = P / float(ps["period_deg"])
        m = round(r)
        if m in (1, 2, 3) and abs(r - m) <= (PERIOD_AGREE if m == 1 else HARMONIC_TOL * m):
            return True
    if log is not None:
        log(f"  the outside description's period {P:.2f} deg spans {cycles:.1f} cycles of the visited angles and is "
            + (f"not the residual's {ps['period_deg']:.2f} deg" if ps is not None and ps.get("period_deg")
               else "not seen in the residual") + ": not established")
    return False


SPRING_SIDE_DEG = 1.0     # the spring asymmetry acts below limp-home (its blend reaches this far above it)
SPRING_SHARE = 0.5        # ... so it is named over the airflow when this share of the angle torque lies there
LINE_KNOTS = 4            # visited knots beyond limp-home needed to take out the line the spring's rate makes there
VISITED_MIN = 5.0         # ... a knot is visited with this many samples near it (as :func:`identified`)


def angle_torque_family(angle_rad, torque_Nm, weight, limp_home_rad: float) -> str:
    """Airflow or spring asymmetry, both a torque of the angle alone, told apart by where the torque acts: the
    spring's asymmetry on the closing side below limp-home only (a second preload and rate there: a kink at
    limp-home), the airflow over the opening (smooth, no kink). ``torque_Nm`` over ``angle_rad`` is a torque
    table learned with its shape free (the generic model's or the family's angle table), ``weight`` how much
    data each knot had.

    Above limp-home a line in angle is what a preload and rate off the nameplate make (the plant file's spring
    is 10-20 % off and the calibration trades it with the table): it says nothing about either family. So the
    weighted line through the visited knots beyond limp-home's blend (not the open stop's end knot, whose value
    the stop's contact balances) is taken out first, when LINE_KNOTS of them are visited; what is left is the
    spring's kink (below limp-home) or the airflow's curvature (over the opening). The share of sum |T - line| w
    below limp-home + SPRING_SIDE_DEG (or half a knot spacing, if wider) decides (SPRING_SHARE). Measured
    (spring_asymmetry@2 random closed s35, random limp-home 7.9 deg): the table +60 -> +28 mN m linearly over
    11-72 deg and -52 mN m at 6 deg; the raw share 0.27 said airflow, the share of what the line leaves 0.97."""
    a = np.asarray(angle_rad, float)
    t = np.asarray(torque_Nm, float)
    wt = np.asarray(weight, float)
    if not np.isfinite(limp_home_rad) or a.size == 0:
        return "airflow_torque"
    step = float(np.median(np.diff(a))) if a.size > 1 else 0.0       # a coarse table smears a step by a knot
    side = a < limp_home_rad + max(np.radians(SPRING_SIDE_DEG), 0.5 * step)
    dev = t
    beyond = ~side & (wt >= VISITED_MIN) & (np.arange(a.size) < a.size - 1)
    if beyond.sum() >= LINE_KNOTS:
        sw = np.sqrt(wt[beyond])
        basis = np.stack([np.ones(a.size), a - limp_home_rad], axis=1)
        coef = np.linalg.lstsq(basis[beyond] * sw[:, None], t[beyond] * sw, rcond=None)[0]
        dev = t - basis @ coef
    w = np.abs(dev) * wt
    tot = float(w.sum())
    if not tot > 1e-6 * float(np.sum(np.abs(t) * wt)):       # nothing (or a line alone): no kink at limp-home
        return "airflow_torque"
    return "spring_asymmetry" if float(w[side].sum()) >= SPRING_SHARE * tot else "airflow_torque"


FAMILY_NFEV = 40        # evaluations of a family's formula fit before its table (as explain.FULL_NFEV)
ANGLE_ONLY = ("airflow_torque", "spring_asymmetry")   # one table for both: a torque of the angle alone
FAMILY_TIE = 0.02       # families whose tables' held-out errors are this close: the better formula decides
HELD_AT_NOISE = 4.0     # a held-out error (mean square, noise units) this low leaves nothing for another family


def outdone_by_description(h_family: float, h_description: float) -> bool:
    """Does the outside description predict the held-out folds so much better than a catalogue family with its
    own table that the family cannot be the explanation: the description leaves no more than the noise
    (HELD_AT_NOISE, mean square in noise units) and the family an order more (1 / GAIN_OUT times)? A physical
    model that explains the data an order worse than a free description, which explains all of it, is not what
    the data show; a description short of the noise may still owe its edge to its freedom (the friction reading
    of :func:`catalogue_alternative`: angle_dependent_friction@1 random open s38, series 12.8, friction 146)."""
    return bool(math.isfinite(h_description) and h_description <= HELD_AT_NOISE
                and not h_family <= h_description / GAIN_OUT)


@dataclasses.dataclass
class FamilyAlternative:
    """A catalogue family that describes what the generic tables found: its formula fit, its refinement
    (family_table.Refinement or None), the held-out error of formula + table and of the formula alone."""

    id: str
    formula: F.FitResult
    refinement: object
    heldout: float
    heldout_formula: float

    @property
    def fit(self) -> F.FitResult:
        r = self.refinement
        return r.fit if (r is not None and r.kept) else self.formula


def _try_family(cur: F.FitResult, cid: str, data: Data, log) -> FamilyAlternative | None:
    """``cid``'s formula added to ``cur`` and fitted (coarse scan of its main parameter first), then refined by
    its table (family_table.refine_family); None when the model cannot be simulated."""
    from .candidates import CANDIDATES
    from .family_table import refine_family
    c = CANDIDATES[cid]
    spec = cur.spec.with_candidate(c)
    x0 = np.concatenate([cur.x, np.zeros(len(spec.params) - len(cur.x))])
    try:
        formula = F.fit(spec, data, x0, max_nfev=FAMILY_NFEV, scan=len(cur.x))
        ref = refine_family(formula, cid, data, log=lambda *a: None)
        if ref is not None:
            return FamilyAlternative(cid, formula, ref, ref.heldout_map if ref.kept else ref.heldout_formula,
                                     ref.heldout_formula)
        ids = ("nominal",) + tuple(k.id for k in spec.candidates)
        h = heldout_error(Problem.make(spec, formula.x, ids), data)
        return FamilyAlternative(cid, formula, None, h, h)
    except (ValueError, TypeError, FloatingPointError, ZeroDivisionError, OverflowError, np.linalg.LinAlgError) as e:
        log(f"  {cid} as the generic tables' family: could not be fitted ({e})")
        return None


def catalogue_alternative(generic: Generic, cur: F.FitResult, family_of_term: dict, data: Data, significant,
                          log=print, resolves=None, screened: tuple = (), ps: dict | None = None,
                          h_catalogue: float | None = None) -> FamilyAlternative | None:
    """Before a residual is called outside the catalogue: the catalogue families that act through the generic
    model's significant tables, the dominant one's first (``family_of_term``: an angle torque -> airflow, spring
    asymmetry, angle-dependent friction; a current torque -> shaft flux loss, torque-constant error; ...) are each added to ``cur`` with
    their formula and their own table (shape learned from the data), and the best is returned when it does the
    generic model's job with one table instead of four: its held-out error within GAIN_OUT of the generic's
    (the generic tables may not win by their extra freedom alone), or its residual within the noise, and it
    lowers the RMS by RMS_GAIN; or, with ``resolves`` (FitResult -> bool: a closed loop's persistent structure
    accounted for, the rule that accepts a candidate in the selection; the loop hides the effect from the angle's
    RMS and held-out error), it accounts for that structure. A periodic angle torque (no catalogue family is
    periodic in angle: neither the generic angle table nor the family's own may be) is no alternative. Among families
    whose errors are within FAMILY_TIE, the better formula is taken, but airflow and spring asymmetry (one
    table) are told apart by where the generic angle torque acts (:func:`angle_torque_family`). ``screened``: further
    families tried with the others (refine passes, in a closed loop, the screening's leader that the selection
    refused: its formula's shape may be what kept it from accounting for the loop's structure). ``h_catalogue``: the
    held-out error of the catalogue model the selection built (refine's), which the open-loop friction reading of a
    series whose period is not established must not predict worse than (GAIN_OUT)."""
    from .candidates import CANDIDATES
    periodic = periodic_term(generic.shape) is not None
    dom = generic.shape.get("significant_terms", [])
    if not dom:
        return None
    named = {c.id for c in cur.spec.candidates}
    # the families of every significant table, the dominant one's first: the generic tables cannot tell a friction
    # band in angle from a torque-constant profile when the current follows the motion (open loop), so the main
    # table alone may leave out the family that is there (angle_dependent_friction@1 random s22: the current's
    # table dominated and only its families were tried; docs/diagnosis-history.md, round 22). In open loop the other
    # tables' families are tried only when none of the main table's predicts the held-out folds to the noise
    # (HELD_AT_NOISE); in a closed loop (``resolves``) always, since the current follows the angle and a table over
    # the one describes the training recording as well as one over the other (airflow_torque@1 3B closed s29:
    # shaft_flux_loss's current table at 1.25 took it, the angle table's families untried, the twin 8.4x).
    def tried(ids):
        return [a for a in (_try_family(cur, c, data, log) for c in ids) if a is not None and math.isfinite(a.heldout)]
    first = [c for c in family_of_term.get(dom[0], ()) if c not in named]
    rest = [c for c in dict.fromkeys(c for t in dom[1:] for c in family_of_term.get(t, ())) if c not in named and c not in first]
    if periodic:
        # no catalogue family is periodic in angle, but the generic tables have no friction over angle: a friction
        # family's torque opposes the motion (its sign follows the speed's), so a friction band in angle that the
        # generic angle torque took may look periodic there. Only the friction families are tried, and one is kept
        # only when it predicts the held-out folds better than the generic tables (no slack) with a table that is
        # not periodic itself (angle_dependent_friction@1 random open s28: the angle table "periodic" at 33 deg, R2
        # 0.95, nothing tried; angle_dependent_friction with its table: held-out 5.16, twin 1.11x against 27.4x)
        first = [c for c in first + rest if c in CANDIDATES and CANDIDATES[c].family == "friction"]
        rest = []
    # in a closed loop the selection may refuse the family the screening ranked first because its formula's shape
    # cannot account for the loop's structure; with its table it may (angle_dependent_friction@1 3B closed s31:
    # screened at dBIC -184, refused at angle RMS x0.91; the current and voltage tables' families tried, and
    # torque_constant_error named at held-out 16.5, twin 38.6x; angle_dependent_friction with its table 4.75)
    if not periodic:
        rest += [c for c in screened if c not in named and c not in first + rest
                 and c in CANDIDATES and CANDIDATES[c].family != "sensing"]
    alts = tried(first)
    if rest and (resolves is not None or not any(a.heldout <= HELD_AT_NOISE for a in alts)):
        alts += tried(rest)
    if not alts:
        return None
    best = min(a.heldout for a in alts)
    near = [a for a in alts if a.heldout <= (1.0 + FAMILY_TIE) * best]
    alt = min(near, key=lambda a: a.heldout_formula)
    # airflow and spring asymmetry add the same angle table: a held-out difference that the generic tables' freedom
    # could make (GAIN_OUT) is the formulas' start under it, not the physics (airflow_torque@1 random open s34:
    # spring 5.40, airflow 5.91, formulas alone 107 / 108; the generic angle torque over the opening)
    pair = [a for a in alts if a.id in ANGLE_ONLY]
    both = ({a.id: a for a in pair} if alt.id in ANGLE_ONLY and len(pair) == 2
            and max(a.heldout for a in pair) <= min(a.heldout for a in pair) / (1.0 - GAIN_OUT)
            else {a.id: a for a in near})
    if "airflow_torque" in both and "spring_asymmetry" in both and "unmodelled_angle" in generic.tables:
        # one table for both: where the free angle torque acts decides
        ta = generic.tables["unmodelled_angle"].params
        grid = np.asarray(ta.angle_rad)
        alt = both[angle_torque_family(grid, ta.torque_Nm, np.minimum(_visited(grid, data), 200.0),
                                       cur.spec.base.limp_home_rad)]
    log("  families of the generic model's significant tables (" + ", ".join(dom) + "): "
        + ", ".join(f"{a.id} held-out {a.heldout:.3g}" for a in alts) + f"; generic {generic.heldout:.3g}")
    ref = alt.refinement
    if ref is not None and ref.kept and ref.term.cls in (mx.AngleTorqueMap, mx.AngleFrictionMap):
        tab = ref.table()              # a family's own angle table that turns out periodic: a detent, not it
        key = "torque_Nm" if ref.term.cls is mx.AngleTorqueMap else "level_Nm"
        if periodicity(np.degrees(tab["angle_rad"]), np.asarray(tab[key]),
                       periods_deg=resolvable(np.degrees(tab["angle_rad"])))["periodic"]:
            log(f"  {alt.id}'s learned angle table is periodic: no catalogue alternative")
            return None
    rms_cur = _rms_deg(cur.spec, cur.x, data)
    rms_alt = _rms_deg(alt.fit.spec, alt.fit.x, data)
    if periodic:
        if rms_alt <= (1.0 - RMS_GAIN) * rms_cur and alt.heldout < generic.heldout:
            log(f"  {alt.id} with its table predicts the held-out folds better ({alt.heldout:.3g}) than the "
                f"generic tables whose angle torque looked periodic ({generic.heldout:.3g}): a friction over angle")
            return alt
        friction_reading = rms_alt <= (1.0 - RMS_GAIN) * rms_cur and open_loop(data)
        if friction_reading and h_catalogue is not None and alt.heldout > h_catalogue / (1.0 - GAIN_OUT):
            # the catalogue model the selection built predicts the folds better than the friction reading: that
            # reading does not displace it (airflow_torque@1 random open s40: airflow accepted, held-out 6.13; the
            # friction with its table 35.1 was named over a 54.9 deg series, 1.1 cycles, held-out 3.51; round 30, lead)
            log(f"  {alt.id} with its table (held-out {alt.heldout:.3g}) predicts the folds worse than the catalogue "
                f"model ({h_catalogue:.3g}): not read as a friction over angle")
            friction_reading = False
        if friction_reading and outdone_by_description(alt.heldout, generic.heldout):
            # the friction reading stands for "the series is a more flexible stand-in for a friction band"; a series
            # that leaves only the noise on the folds while the friction with its table leaves an order more has not
            # out-fitted the friction by its freedom: it describes a torque the friction does not (detent_torque
            # random open s42: an 18.07 deg series, 2.2 cycles, held-out 1.41; the friction with its table 156, twin
            # 63x, outside 1.94x; the friction truths, adf@1 random open s36 / s38 / s40: series 7.82 / 12.8 / 16.4,
            # short of the noise, against 30.7 / 146 / 23; a ratio alone would lose s38 at 11.4; round 32, i32outside)
            log(f"  {alt.id} with its table (held-out {alt.heldout:.3g}) predicts the folds an order worse than the "
                f"outside description, which leaves the noise ({generic.heldout:.3g}): not read as a friction "
                "over angle")
            friction_reading = False
        if friction_reading and not period_established(generic, ps, data, log):
            # the outside description's "period" is a fit over 1-2 of its cycles that the residual does not repeat:
            # no periodic torque is shown, only a smooth torque over angle plus one per ampere, and in an open loop
            # the current follows the direction of motion (it drives the plate against the friction), so the two
            # together stand in for a friction band; the friction family's torque opposes the motion
            # by construction, and its own table is not periodic (checked above). Open loops only: in a closed loop the
            # controller sets the current, and an airflow torque was named so (airflow_torque@1 3B closed s21, g30adf)
            log(f"  {alt.id} with its table (held-out {alt.heldout:.3g}, generic {generic.heldout:.3g}): the generic "
                "description's period is not established, so it shows no periodic torque: a friction over angle")
            return alt
        log(f"  {alt.id} with its table: held-out {alt.heldout:.3g} against {generic.heldout:.3g} for the generic "
            "tables (periodic in angle): no catalogue alternative")
        return None
    if rms_alt <= (1.0 - RMS_GAIN) * rms_cur and (alt.heldout <= generic.heldout / (1.0 - GAIN_OUT)
                                                   or not significant(alt.fit)):
        return alt
    if resolves is not None and resolves(alt.fit):
        log(f"  {alt.id} with its table accounts for the closed loop's persistent structure")
        return alt
    log(f"  {alt.id} with its table: RMS {rms_alt:.4f} deg against {rms_cur:.4f} deg, held-out "
        f"{alt.heldout:.3g} against {generic.heldout:.3g} for the generic tables: no catalogue alternative")
    return None


PROBE_R2 = 0.5 * PERIODIC_R2   # an angle table this close to periodic is refitted with the current's table fine


def period_hint(shape: dict) -> bool:
    """Does the significant angle table show a period that falls short of the test (R2 >= PROBE_R2 over
    MIN_CYCLES)? A ripple that scales with the current is periodic in the current's table, not in the angle's
    (its amplitude follows the current along the stroke); :func:`refine.refine` then fits the current's table on
    the fine grid, and the decision is that fit's (periodic by PERIODIC_R2, held-out error lower)."""
    a = shape.get("angle", {})
    return bool("unmodelled_angle" in shape.get("significant_terms", []) and not a.get("periodic")
                and a.get("period_deg") and a.get("periodic_r2", 0.0) >= PROBE_R2
                and a.get("cycles", 0.0) >= MIN_CYCLES)


def periodic_term(shape: dict) -> dict | None:
    """The significant table that is periodic in angle (the angle torque's, else the current's): its
    description (periodic, period_deg, ...), or None."""
    sig = shape.get("significant_terms", [])
    for key, term in (("angle", "unmodelled_angle"), ("current", "unmodelled_current")):
        d = shape.get(key, {})
        if d.get("periodic") and term in sig:
            return d
    return None


def residual_period(fit: F.FitResult, data: Data, log=print, every: bool = False) -> dict | None:
    """The periodic-in-angle structure that the model ``fit`` leaves in the observer's innovation
    (disturbance.periodic_structure): its description when significant (or, ``every``, whatever was found),
    else None. A catalogue family whose formula absorbs the mean of a current-proportional ripple (a torque
    constant, a spring asymmetry, an airflow map) leaves the ripple's periodic part there."""
    from .disturbance import periodic_structure
    try:
        ps = periodic_structure(*fit.spec.build(fit.x), data)
    except (ValueError, FloatingPointError, ZeroDivisionError, OverflowError, np.linalg.LinAlgError) as e:
        log(f"  the residual's periodic structure: not computed ({e})")
        return None
    if ps is None:
        return None
    ids = ", ".join(c.id for c in fit.spec.candidates) or "the nominal model"
    log(f"  the residual's periodic structure ({ids}): period {ps['period_deg']:.2f} deg, z {ps['z']:.1f} "
        f"(angle alone {ps['z_angle']:.1f}, per ampere {ps['z_current']:.1f})"
        + (": significant" if ps["significant"] else ""))
    return ps if (every or ps["significant"]) else None


HARMONIC_TOL = 0.05   # a table's period this close to m times the residual's (m = 2, 3): that multiple is tried
PERIOD_AGREE = 0.05        # the series' period and a table's periodogram agree within this share (with_series, disagreeing_period)


def harmonic_period(shape: dict, ps: dict | None) -> float | None:
    """The residual's period (:func:`residual_period`) when the periodic table's period is a multiple of it
    (2 or 3 times, within HARMONIC_TOL): the tables' periodogram can lock on a multiple of the torque's period
    (a 56.1 deg period reported for an 18.7 deg detent: the multiple's third harmonic is the torque's
    fundamental); None otherwise."""
    d = periodic_term(shape)
    if d is None or ps is None or not d.get("period_deg") or not ps.get("period_deg"):
        return None
    r = float(d["period_deg"]) / float(ps["period_deg"])
    m = round(r)
    return float(ps["period_deg"]) if m in (2, 3) and abs(r - m) <= HARMONIC_TOL * m else None


def disagreeing_period(shape: dict, ps: dict | None) -> float | None:
    """The residual's period (:func:`residual_period`) when it and the periodic table's disagree by more than
    PERIOD_AGREE and are not multiples of each other (that case is :func:`harmonic_period`'s), and one part of the
    residual's structure alone carries it (``one_part``, as a period the report may give): two estimates of one
    torque's period, from the tables fitted by output error and from the observer's innovation in steady motion,
    and the held-out folds decide between their series. detent_torque 3B open seed 32 (a 24.06 deg detent of
    50 mN m): the angle table's periodogram gave 16.9 deg (R2 0.86; the training holds at 3, 25, 68, 78 and 90 deg
    and passes the rest at speed), the residual 23.5 deg (z 3.0, angle alone 4.3); the series started from 16.9
    deg stayed there (held-out 1.43e3, twin 108x the noise on the closed held-out recording), the one from 23.5
    deg went to 24.17 deg (held-out 85)."""
    d = periodic_term(shape)
    if d is None or ps is None or not d.get("period_deg") or not ps.get("period_deg") or not ps.get("one_part"):
        return None
    Pt, Pr = float(d["period_deg"]), float(ps["period_deg"])
    if abs(Pt - Pr) <= PERIOD_AGREE * Pr or harmonic_period(shape, ps) is not None:
        return None
    r = max(Pt, Pr) / min(Pt, Pr)
    if round(r) in (2, 3) and abs(r - round(r)) <= HARMONIC_TOL * round(r):    # the residual's a multiple
        return None
    return Pr


def with_period(g: Generic, period_deg: float) -> Generic:
    """``g`` with its periodic table's period replaced (the tables' own estimate kept as period_table_deg)."""
    d = periodic_term(g.shape)
    key = "angle" if d is g.shape.get("angle") else "current"
    return dataclasses.replace(g, shape={**g.shape, key: {**d, "period_deg": period_deg,
                                                          "period_table_deg": d["period_deg"]}})


def removes_period(g: Generic, ps: dict | None, rms_nominal_deg: float, data: Data, log=print) -> bool:
    """Does the outside description ``g`` (periodic in angle) remove the significant periodic structure ``ps``
    that the catalogue model left (disturbance.resolved on its z), and lower the nominal model's RMS by
    RMS_GAIN? Then the catalogue model is not the explanation, whatever its held-out error: the catalogue has no
    torque periodic in angle, so a catalogue family that fits as well has absorbed only the ripple's mean."""
    if ps is None or periodic_term(g.shape) is None or not math.isfinite(g.rms_deg):
        return False
    if g.rms_deg > (1.0 - RMS_GAIN) * rms_nominal_deg:
        return False
    if not period_established(g, ps, data, log):
        return False
    from .disturbance import resolved
    after = residual_period(g.fit, data, log=log, every=True)
    z = after["z"] if after is not None else 0.0
    ok = resolved(ps["z"], z)
    log(f"  the outside description leaves periodic structure z {z:.1f} of the catalogue model's {ps['z']:.1f}"
        + (": it removes it" if ok else ""))
    return ok
