"""The penalized Gauss-Newton fit of a model with lookup tables (docs/diagnosis-shapes.md).

A :class:`Problem` is a model (spec) with tables (map terms, :mod:`.shapes`), its normalized parameters x and
which of them are free. The tables' knot values c are found by output error together with the calibrated nominal
parameters (the model's other parameters stay at their fitted values):

    minimize  |r(x)|^2 + lambda |D c|^2 + |x_nom / sigma|^2
                                  r: the diagnosis's normalized residual (fit.make_fun)
                                  D: second differences of the knot values (roughness)
                                  x_nom: the nominal parameters, 0 at the nameplate (sigma: NOMINAL_PRIOR of it)

by Gauss-Newton on a finite-difference Jacobian (:func:`fit_penalized`; the table is linear in c, but a formula
fit far from the optimum, its nominal parameters bent to the wrong shape, needs more than three iterations: up to
GN_ITER). The roughness weight lambda is chosen by cross-validation over the diagnosis's two folds of alternating
0.5 s time blocks (:func:`choose_lambdas`): for each lambda on a log grid the linearized problem is solved on one
fold and the angle residual predicted on the other (``fit.fold_masks`` layout). The *held-out error* of a model
(formula or map) is measured the same way for both, but with the true simulation on the held-out fold: every free
parameter refitted on one fold by one regularized Gauss-Newton step from the full-data optimum, the other fold's
angle residual simulated, summed over both folds (:func:`heldout_error`).

Where the recordings did not go the table is not identified, and the roughness penalty alone would extrapolate
the last visited slope (a straight line in the correction, out to the stop). Such knots (less than VISIT_MIN_S of
hat-weighted time near them, :func:`.shapes.visit_time_s`) are *anchored*: pulled to 0 with ANCHOR times the
weight of a roughness row, so the twin falls back to the family's formula (or, for the generic tables, to the
calibrated nominal model) where the recordings did not go. Beyond the visited range a family's table over angle
does not return to the formula but holds formula + table at its value at the last visited knot
(:func:`hold_rows`): a formula fitted to part of the stroke is not extrapolated (docs/diagnosis-history.md, round
14). The same holds for knots the recordings visited without seeing them: where the plate sits against a stop or
in the spring's limp-home band a torque change does not move it, so a knot whose Jacobian column has less than
ID_MIN of its table's median energy (first linearization of :func:`fit_penalized`) is anchored as well
(:func:`anchor_unidentified`; measured: an airflow plateau's table, free at the 0 and 6 deg knots, put 5-9 mN m at
limp-home and the closed stop, where a closed loop holds the plate: 0.9 deg off there).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from . import fit as F
from .model import Data, Spec, _layout, residuals, simulate
from .shapes import MapTerm, VISIT_MIN_S, visit_time_s


LAMBDAS = tuple(10.0 ** np.arange(-3.0, 3.5, 0.5))   # roughness weights (relative, see _penalty_scale)
GN_ITER = 8             # Gauss-Newton iterations at most (stops when the objective falls by < 0.5 %)
FD_STEP = 0.5            # finite-difference step in normalized units (a knot value moves by FD_STEP * scale)
JAC_SUBSTEPS = 20       # Jacobians at this integrator step (the residual at the model's own)
RIDGE = 1e-4             # a small pull of the table towards zero (collinearity with the spring)
ANCHOR = 1e3             # a knot the recordings did not visit (shapes.VISIT_MIN_S) is pulled to 0 (the formula
                         # alone) with this weight, relative to a roughness row
ID_MIN = 0.01           # a knot whose Jacobian column carries less than this share of its table's median is not
                         # identified either (the plate pinned at a stop or in the limp-home band): anchored too


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
