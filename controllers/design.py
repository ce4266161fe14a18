"""Controller design from the core plant: numerical linearization and loop shaping.

Linearization (:func:`linearize`)
    The core plant's generated ``rhs`` (the same equations the simulator integrates) is differentiated by
    central differences around an equilibrium: plate at rest at ``phi0``, holding current
    i0 = T_spring(phi0)/k, voltage u0 = R i0. States x = [phi, omega, i, <friction states>], input the
    coil voltage u [V], output the angle [rad]. Friction is treated in one of two documented ways:

    "sliding"     the friction component is replaced by its sliding-regime slope, the viscous
                  sigma2*omega (model-1 friction). The Coulomb level T_c is a bias that the
                  controllers' friction compensation cancels; what is left is linear.
    "presliding"  the LuGre/Dahl component is kept with the bristle state z = 0: the plate at rest
                  behaves as a stiff spring sigma0 (100 Nm/rad) damped by sigma1 + sigma2. This is the
                  loop the controller closes around a plate that sticks, so it must be stable too
                  (otherwise the compensated loop limit-cycles around the target).

    The end stops are removed (the operating points are inside the travel). At phi0 away from limp-home
    the spring slope is R_F; at limp-home it is R_F + T_SP0/eps (the arm contact).

Discrete PID design (:func:`design_pid`)
    Plant P(z) = ZOH discretisation at the control period T. Controller (derivative on the filtered
    differentiator D(z) of :class:`~etb_gym.controllers.base.VelocityEstimator`, integrator backward Euler):

        C(z) = Kp * (1 + w_i T z/(z - 1) + T_d D(z)),        Ki = Kp w_i,  Kd = Kp T_d

    For a crossover w_c and a phase margin PM: w_i = w_c / integral_ratio, T_d is the root of
    arg L(e^{j w_c T}) = -180 deg + PM (bisection), Kp = 1 / |L(e^{j w_c T})| / Kp. The achieved gain and
    phase margins of the discrete loop are then measured with ``control.stability_margins``.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from etb_gym import Plant, make_plant
from etb_gym.components.friction import ViscousFriction

from .base import VelocityEstimator, check_gain
from .model import NominalModel, model_for_key, resolve_model

FRICTION_TREATMENTS = ("sliding", "presliding")


@dataclass
class Linearization:
    """A linear model of the plant around one operating point."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    state_names: tuple
    phi0_rad: float
    i0_A: float
    u0_V: float
    friction: str

    def ss(self):
        import control

        return control.ss(self.A, self.B, self.C, np.zeros((1, 1)))

    def tf(self):
        """The angle/voltage transfer function, with the modes the input cannot move removed (the
        presliding model has one: z - phi is constant at rest)."""
        import control

        return control.minreal(control.ss2tf(self.ss()), tol=1e-3, verbose=False)

    def discrete(self, dt: float):
        """ZOH discretisation at the control period (the PWM duty is held for one period)."""
        import control

        return control.c2d(self.tf(), dt, method="zoh")

    def poles(self):
        return np.linalg.eigvals(self.A)


def _linear_plant(plant: Plant, friction: str) -> Plant:
    if friction not in FRICTION_TREATMENTS:
        raise ValueError(f"friction treatment {friction!r} is unknown: expected one of {FRICTION_TREATMENTS}")
    if friction == "sliding" or plant.friction is None:
        visc = getattr(plant.friction.params, "viscous_Nm_s_per_rad", 0.0) if plant.friction is not None else 0.0
        return plant.replace(friction=ViscousFriction(viscous_Nm_s_per_rad=visc), stops=None)
    return plant.replace(stops=None)


def linearize(plant: Plant | NominalModel | str | None = None, phi0_rad: float | None = None,
              friction: str = "sliding", rel_step: float = 1e-6) -> Linearization:
    """Numerical Jacobian of the core plant at rest at ``phi0_rad`` (default limp-home + 10 deg)."""
    if isinstance(plant, NominalModel):
        plant = plant.plant
    elif not isinstance(plant, Plant):
        plant = make_plant("3B" if plant is None else plant)
    nom = NominalModel.from_plant(plant)
    if phi0_rad is None:
        phi0_rad = nom.limp_home_rad + math.radians(10.0)
    phi0_rad = check_gain("linearize", "phi0_rad", phi0_rad)
    lin = _linear_plant(plant, friction)
    k = float(np.asarray(plant.drive.torque_constant(phi0_rad)))
    i0 = nom.spring_torque_Nm(phi0_rad) / k
    x0 = lin.initial_state(phi0_rad, at_rest=False)
    x0[2] = i0
    n = lin.n_states
    P = lin.P
    aux = np.zeros(len(lin.components))
    rhs = lin.stepper("plain").rhs

    def f(x, u):
        dx = np.empty(n)
        rhs(0.0, x, u, P, dx, aux)
        return dx

    # u0: the voltage that holds i0 (the drive's own voltage drop at rest)
    dx_probe = f(x0, 0.0)
    L0 = 1.0 / ((f(x0, 1.0)[2] - dx_probe[2]))
    u0 = -dx_probe[2] * L0
    A = np.empty((n, n))
    for j in range(n):
        h = rel_step * max(1.0, abs(x0[j]))
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h
        xm[j] -= h
        A[:, j] = (f(xp, u0) - f(xm, u0)) / (2 * h)
    hu = rel_step * max(1.0, abs(u0))
    B = ((f(x0, u0 + hu) - f(x0, u0 - hu)) / (2 * hu)).reshape(n, 1)
    C = np.zeros((1, n))
    C[0, 0] = 1.0
    return Linearization(A, B, C, lin.state_names, float(phi0_rad), float(i0), float(u0), friction)


# ------------------------------------------------------------------------------------------------ PID design
@dataclass
class PIDDesign:
    """Designed PID gains (voltage per radian) and the loop they make."""

    kp_V_per_rad: float
    ki_V_per_rad_s: float
    kd_V_s_per_rad: float
    crossover_rad_s: float
    phase_margin_target_deg: float
    derivative_cutoff_rad_s: float
    dt: float
    phi0_rad: float
    gain_margin: float = field(default=float("nan"))
    phase_margin_deg: float = field(default=float("nan"))
    gain_crossover_rad_s: float = field(default=float("nan"))
    phase_crossover_rad_s: float = field(default=float("nan"))
    closed_loop_stable: bool = False
    presliding_gain_margin: float = field(default=float("nan"))
    rolloff_rad_s: float = math.inf

    def controller_tf(self):
        """C(z) in V per rad of error (derivative acting through the velocity estimator)."""
        import control

        T = self.dt
        integ = control.tf([T, 0.0], [1.0, -1.0], T)
        D = VelocityEstimator(T, self.derivative_cutoff_rad_s).transfer_function()
        return control.minreal((self.kp_V_per_rad + self.ki_V_per_rad_s * integ + self.kd_V_s_per_rad * D)
                               * rolloff_tf(self.rolloff_rad_s, T), verbose=False)

    def summary(self) -> str:
        return (f"phi0 {math.degrees(self.phi0_rad):6.2f} deg: Kp {self.kp_V_per_rad:8.3f} V/rad, "
                f"Ki {self.ki_V_per_rad_s:9.2f} V/(rad s), Kd {self.kd_V_s_per_rad:7.4f} V s/rad, "
                f"roll-off {self.rolloff_rad_s:5.0f} rad/s | "
                f"crossover {self.gain_crossover_rad_s:6.1f} rad/s, PM {self.phase_margin_deg:5.1f} deg, "
                f"GM {20 * math.log10(self.gain_margin) if self.gain_margin > 0 and math.isfinite(self.gain_margin) else float('inf'):5.1f} dB, "
                f"presliding GM {20 * math.log10(self.presliding_gain_margin) if self.presliding_gain_margin > 0 and math.isfinite(self.presliding_gain_margin) else float('inf'):5.1f} dB")


def eval_tf(sys, z):
    """A SISO transfer function evaluated at the points ``z``."""
    num = np.asarray(sys.num[0][0], float)
    den = np.asarray(sys.den[0][0], float)
    return np.polyval(num, z) / np.polyval(den, z)


def grid_margins(w, Lw):
    """Gain margin, phase margin [deg] and gain crossover of a loop sampled on a frequency grid
    (fast screening; the chosen design is confirmed with control.stability_margins)."""
    mag = np.abs(Lw)
    ph = np.unwrap(np.angle(Lw))
    # reference the phase so that low frequencies sit in (-270, 90]
    ph = ph - 2 * math.pi * np.round((ph[0] + math.pi / 2) / (2 * math.pi))
    k = np.nonzero((mag[:-1] >= 1) & (mag[1:] < 1))[0]
    if k.size == 0:
        if mag[0] >= 1:
            return 0.0, -180.0, float("nan")
        pm, wgc = math.inf, float("nan")          # |L| < 1 everywhere: no gain crossover
    else:
        j = k[-1]
        wgc = float(w[j])
        pm = math.degrees(ph[j]) + 180.0
        pm = (pm + 180.0) % 360.0 - 180.0
    c = np.nonzero(np.diff(np.sign(ph + math.pi)) != 0)[0]
    gms = [1.0 / mag[i] for i in c if w[i] > 0]
    gm = min(gms) if gms else math.inf
    return float(gm), float(pm), wgc


def loop_margins(loop):
    """(gain margin [abs], phase margin [deg], w_gain_crossover, w_phase_crossover) of a discrete loop."""
    import control

    gm, pm, _, wpc, wgc, _ = control.stability_margins(loop, returnall=False)
    return float(gm), float(pm), float(wgc), float(wpc)


def closed_loop_stable(loop) -> bool:
    import control

    cl = control.feedback(loop, 1)
    return bool(np.all(np.abs(control.poles(cl)) < 1.0 - 1e-9))


def rolloff_tf(cutoff_rad_s: float, dt: float, damping: float = 0.7):
    """Second-order low-pass on the controller output (Tustin), 1 for cutoff = inf."""
    import control

    if not math.isfinite(cutoff_rad_s):
        return control.tf([1.0], [1.0], dt)
    w = cutoff_rad_s
    return control.c2d(control.tf([w * w], [1.0, 2 * damping * w, w * w]), dt, method="tustin")


def design_pid(plant=None, phi0_rad: float | None = None, crossover_rad_s: float = 50.0,
               phase_margin_deg: float = 50.0, integral_ratio: float = 4.0, derivative_cutoff_rad_s: float = 600.0,
               derivative_times_s=(0.0, 0.001, 0.002, 0.004, 0.006, 0.008, 0.012),
               rolloff_cutoffs_rad_s=(80.0, 120.0, 160.0, 240.0, math.inf), dt: float | None = None) -> PIDDesign:
    """PID gains for crossover ``crossover_rad_s`` and at least ``phase_margin_deg`` of phase margin.

    The plant's electro-mechanical mode (L with J through the back-EMF, ~220 rad/s, damping ~0.2) limits
    the gain margin, so the design searches the derivative time T_d and the output roll-off cut-off w_r
    for the largest gain margin among the designs that reach the phase margin; Kp puts the crossover at
    w_c, Ki = Kp w_c / integral_ratio. Raises ValueError if no candidate reaches the phase margin."""
    import control

    wc = check_gain("design_pid", "crossover_rad_s", crossover_rad_s, positive=True)
    pm_min = check_gain("design_pid", "phase_margin_deg", phase_margin_deg, positive=True, upper=90.0)
    ratio = check_gain("design_pid", "integral_ratio", integral_ratio, positive=True)
    wf = check_gain("design_pid", "derivative_cutoff_rad_s", derivative_cutoff_rad_s, positive=True)
    nom = resolve_model(plant) if not isinstance(plant, Plant) else NominalModel.from_plant(plant)
    T = nom.control_period_s if dt is None else check_gain("design_pid", "dt", dt, positive=True)
    if wc >= math.pi / T / 2:
        raise ValueError(f"design_pid.crossover_rad_s = {wc!r} is invalid: expected a value below a quarter "
                         f"of the sampling rate ({math.pi / T / 2:.0f} rad/s)")
    lin = linearize(nom.plant, phi0_rad, "sliding")
    Pd = lin.discrete(T)
    integ = control.tf([T, 0.0], [1.0, -1.0], T)
    D = VelocityEstimator(T, wf).transfer_function()
    best = None
    tried = []
    w = np.logspace(0, math.log10(0.999 * math.pi / T), 3000)
    zz = np.exp(1j * w * T)
    Pw = eval_tf(Pd, zz)
    Iw = T * zz / (zz - 1)
    Dw = VelocityEstimator(T, wf).frequency_response(zz)
    for td in derivative_times_s:
        for wr in rolloff_cutoffs_rad_s:
            Fw = eval_tf(rolloff_tf(wr, T), zz)
            Lw = (1 + (wc / ratio) * Iw + td * Dw) * Fw * Pw
            kp = 1.0 / abs(np.interp(wc, w, np.abs(Lw)))
            gm, pm, wgc = grid_margins(w, kp * Lw)
            tried.append(pm)
            if not (pm >= pm_min and abs(wgc - wc) < 0.05 * wc):
                continue
            if best is None or gm > best[0]:
                best = (gm, pm, wgc, float("nan"), kp, td, wr)
    if best is not None:
        # confirm the winner with python-control (exact margins, closed-loop poles)
        gm, pm, wgc, wpc, kp, td, wr = best
        shape = (1 + (wc / ratio) * integ + td * D) * rolloff_tf(wr, T)
        loop = kp * shape * Pd
        if not closed_loop_stable(loop):
            best = None
        else:
            best = (*loop_margins(loop), kp, td, wr)
    if best is None:
        raise ValueError(f"design_pid: no PID reaches a phase margin of {pm_min} deg at a crossover of {wc} rad/s "
                         f"(best {max(tried):.1f} deg); lower crossover_rad_s or phase_margin_deg")
    gm, pm, wgc, wpc, kp, td, wr = best
    d = PIDDesign(kp, kp * wc / ratio, kp * td, wc, pm_min, wf, T, lin.phi0_rad, rolloff_rad_s=wr)
    d.gain_margin, d.phase_margin_deg, d.gain_crossover_rad_s, d.phase_crossover_rad_s = gm, pm, wgc, wpc
    d.closed_loop_stable = True
    if nom.bristle_stiffness_Nm_per_rad > 0:
        pre = linearize(nom.plant, phi0_rad, "presliding").discrete(T)
        d.presliding_gain_margin = loop_margins(d.controller_tf() * pre)[0]
    return d


def max_stable_gain(plant=None, phi0_rad: float | None = None, friction: str = "presliding",
                    dt: float | None = None) -> float:
    """Largest proportional gain [V/rad] that keeps the loop around the (presliding) plant stable.

    Used to size the linear zone of the friction compensator: near zero error it acts as an extra
    proportional gain and must not destabilise the plate stuck in its bristles."""
    import control

    nom = resolve_model(plant) if not isinstance(plant, Plant) else NominalModel.from_plant(plant)
    T = nom.control_period_s if dt is None else dt
    Pd = linearize(nom.plant, phi0_rad, friction).discrete(T)
    gm, _, _, _ = loop_margins(Pd)
    return float(gm)


def describe_plant(plant=None, phi0_rad=None) -> str:
    """Poles of both linearizations (printed by ``etb-gym design``)."""
    out = []
    for fr in FRICTION_TREATMENTS:
        lin = linearize(plant, phi0_rad, fr)
        p = np.sort_complex(lin.poles())
        out.append(f"{fr:10s} phi0 {math.degrees(lin.phi0_rad):.2f} deg, i0 {lin.i0_A:.3f} A, u0 {lin.u0_V:.3f} V, "
                   f"poles [rad/s]: " + ", ".join(f"{q.real:.1f}{q.imag:+.1f}j" if abs(q.imag) > 1e-6 else f"{q.real:.1f}"
                                                  for q in p))
    return "\n".join(out)


# ------------------------------------------------------------------------------------------------ cached designs
@functools.lru_cache(maxsize=64)
def scheduled_pid_designs(key: str, crossover: float, pm: float, ratio: float, wf: float, angles_deg: tuple):
    """``design_pid`` at each scheduling angle of the model ``key`` (controllers.model.model_key), cached."""
    nom = model_for_key(key)
    return tuple(design_pid(nom.plant, math.radians(a), crossover_rad_s=crossover, phase_margin_deg=pm,
                            integral_ratio=ratio, derivative_cutoff_rad_s=wf) for a in angles_deg)


@functools.lru_cache(maxsize=64)
def presliding_gain_limit(key: str, angle_deg: float) -> float:
    """``max_stable_gain`` of the presliding plant of model ``key`` at ``angle_deg``, cached."""
    return max_stable_gain(model_for_key(key).plant, math.radians(angle_deg), "presliding")


@functools.lru_cache(maxsize=64)
def smc_layer_gain(key: str, lam: float, wf: float, gm_db: float, pm_deg: float,
                   angles_deg: tuple = (13.0, 40.0, 80.0)) -> float:
    """Largest boundary-layer gain G = K/Phi [V s/rad] of the voltage-mode sliding-mode controller whose
    linearized loop C = G (D(z) + lambda) + (R J / k) lambda D(z) keeps ``gm_db`` / ``pm_deg`` of margin at
    every angle (grid search over G)."""
    nom = model_for_key(key)
    T = nom.control_period_s
    w = np.logspace(0, math.log10(0.999 * math.pi / T), 3000)
    zz = np.exp(1j * w * T)
    Dw = VelocityEstimator(T, wf).frequency_response(zz)
    plants = [eval_tf(linearize(nom.plant, math.radians(ang), "sliding").discrete(T), zz) for ang in angles_deg]
    rj_k = nom.resistance_ohm * nom.inertia_kg_m2 / nom.torque_constant_Nm_per_A
    best = None
    for G in np.logspace(-3, 1, 200):
        ok = True
        for Pw in plants:
            Cw = G * (Dw + lam) + rj_k * lam * Dw
            gm, pm, _ = grid_margins(w, Cw * Pw)
            if not (gm > 0 and 20 * math.log10(gm) >= gm_db and pm >= pm_deg):   # gm 0: |L| >= 1 up to Nyquist
                ok = False
                break
        if ok:
            best = G
    if best is None:
        raise ValueError(f"SlidingModeController: no layer gain gives {gm_db} dB / {pm_deg} deg of margin with "
                         f"lambda = {lam} rad/s; lower lambda")
    return float(best)


def current_feedback_poles(plant, phi0_rad: float, gain_V_per_A: float) -> np.ndarray:
    """Poles of the sliding-friction linearization with the coil current fed back, u = -K_c i (the inner
    current loop's damping of the electro-mechanical mode)."""
    lin = linearize(plant, phi0_rad, "sliding")
    K = np.zeros((1, lin.A.shape[0]))
    K[0, 2] = gain_V_per_A
    return np.linalg.eigvals(lin.A - lin.B @ K)


def _mode_text(poles) -> str:
    p = [q for q in np.sort_complex(poles) if q.imag > 1e-6]
    if not p:
        return "no oscillatory mode"
    q = p[0]
    return f"{abs(q):.0f} rad/s, damping {-q.real / abs(q):.2f}"
