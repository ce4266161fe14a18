"""Electric drives of the permanent-magnet actuator (paper sec. 4): models A, B and C.

All three share the coil loop (Kirchhoff, eq. 3 with the back-EMF sign corrected, see docs/model.md):

    L(i, phi) * di/dt = u - R*i - k(phi)*omega        torque = k(phi) * i

    A (sec. 4.1)  k = c_M,                L constant
    B (sec. 4.2)  k = c_M,                L = h2(i, phi): parametric map or a measured table
    C (sec. 4.3)  k = k_C*cos(phi),       L constant;   k_C = N * Psi_hat from eq. 13 / Table 1

The back-EMF of C is N*dPsi/dt = N*Psi_hat*cos(phi)*omega, the same k(phi) as its torque, so the drive
converts power without creating energy (i*u_emf = torque*omega).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..jit import kernel
from .base import Component, Params, check, positive


CURRENT_MARGIN = 4.0   # |i| beyond this many times V_supply/R is not physical (the bridge drives at most
                       # 2 V/R: full reverse voltage against a back-EMF of at most V at no-load speed)


@kernel
def drive_current_plausible(phi, omega, i, supply_V, p):
    """The coil current is within what the supply can drive (p[0] is R for every drive)."""
    return abs(i) <= CURRENT_MARGIN * supply_V / p[0]


# --------------------------------------------------------------------------------------------- A
@dataclasses.dataclass(frozen=True)
class LinearDriveParams(Params):
    """Model A: constant R, L and drive constant (paper sec. 4.1)."""

    resistance_ohm: float = 1.25
    inductance_H: float = 0.02
    torque_constant_Nm_per_A: float = 0.132

    def validate(self):
        positive("LinearDriveParams", self, "resistance_ohm", "inductance_H", "torque_constant_Nm_per_A")


@kernel
def linear_drive_kernel(t, phi, omega, i, u, s, p, ds):
    R = p[0]
    L = p[1]
    k = p[2]
    return k * i, R * i + k * omega, L


class LinearDrive(Component):
    kind = "drive.A"
    role = "drive"
    Params = LinearDriveParams
    kernel = staticmethod(linear_drive_kernel)
    plausible = staticmethod(drive_current_plausible)
    description = "A: linear drive, constant R, L, c_M (sec. 4.1)"

    def torque_constant(self, phi):
        return np.full_like(np.asarray(phi, float), self.params.torque_constant_Nm_per_A)

    def inductance(self, i, phi):
        return np.full(np.broadcast(np.asarray(i), np.asarray(phi)).shape, self.params.inductance_H)


# --------------------------------------------------------------------------------------------- B
@dataclasses.dataclass(frozen=True)
class NonlinearInductanceDriveParams(Params):
    """Model B: the inductance L = h2(i, phi) (paper sec. 4.2, Fig. 7).

    The paper gives h2 only as a figure. Our parametric map, saturating in current and falling with
    angle:

        L(i, phi) = L0 * (1 - a_phi * phi / (pi/2)) * (r_inf + (1 - r_inf) / (1 + (i / i_sat)^2))

    ``inductance_table`` replaces the map by a measured table (see :class:`InductanceTable`).
    """

    resistance_ohm: float = 1.25
    torque_constant_Nm_per_A: float = 0.132
    inductance_H: float = 0.02                 # L0: small-signal value at i = 0, phi = 0 (paper's L)
    saturated_inductance_ratio: float = 0.3    # r_inf: L(i -> inf) / L(0)
    saturation_current_A: float = 3.0          # i_sat: current at which L has fallen by half of (1 - r_inf)
    angle_coefficient: float = 0.2             # a_phi: relative drop of L from closed to 90 deg
    inductance_table: "InductanceTable | None" = None

    def validate(self):
        n = "NonlinearInductanceDriveParams"
        positive(n, self, "resistance_ohm", "torque_constant_Nm_per_A", "inductance_H", "saturation_current_A")
        r = self.saturated_inductance_ratio
        check(n, "saturated_inductance_ratio", r, 0 < r <= 1, "a ratio in (0, 1]")
        a = self.angle_coefficient
        check(n, "angle_coefficient", a, 0 <= a < 1, "a value in [0, 1) (L must stay positive at 90 deg)")
        if self.inductance_table is not None and not isinstance(self.inductance_table, InductanceTable):
            raise ValueError(f"{n}.inductance_table must be an InductanceTable, got {type(self.inductance_table).__name__}")

    def to_dict(self):
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["inductance_table"] = None if self.inductance_table is None else self.inductance_table.to_dict()
        return d


@dataclasses.dataclass(frozen=True, eq=False)
class InductanceTable:
    """A measured inductance map L(|i|, phi): bilinear interpolation, clamped at the grid edges.

    ``current_A`` (n_i,) and ``angle_rad`` (n_phi,) strictly increasing, ``inductance_H`` (n_i, n_phi) > 0.
    The map is even in current: L(-i) = L(i).
    """

    current_A: tuple
    angle_rad: tuple
    inductance_H: tuple

    def __post_init__(self):
        ci = np.asarray(self.current_A, float)
        ap = np.asarray(self.angle_rad, float)
        L = np.asarray(self.inductance_H, float)
        n = "InductanceTable"
        check(n, "current_A", self.current_A, ci.ndim == 1 and ci.size >= 2, "a 1-D grid of at least 2 currents")
        check(n, "angle_rad", self.angle_rad, ap.ndim == 1 and ap.size >= 2, "a 1-D grid of at least 2 angles")
        check(n, "current_A", self.current_A, bool(np.all(np.isfinite(ci))) and bool(np.all(np.diff(ci) > 0)),
              "finite, strictly increasing currents")
        check(n, "current_A", self.current_A, ci[0] >= 0, "currents >= 0 (the map is even in current)")
        check(n, "angle_rad", self.angle_rad, bool(np.all(np.isfinite(ap))) and bool(np.all(np.diff(ap) > 0)),
              "finite, strictly increasing angles")
        check(n, "inductance_H", f"array of shape {L.shape}", L.shape == (ci.size, ap.size),
              f"shape (len(current_A), len(angle_rad)) = ({ci.size}, {ap.size})")
        bad = np.argwhere(~np.isfinite(L) | (L <= 0))
        if bad.size:
            r, c = bad[0]
            raise ValueError(f"{n}.inductance_H[{r}][{c}] = {L[r, c]!r} is invalid: expected a finite value > 0 H")
        object.__setattr__(self, "current_A", tuple(map(float, ci)))
        object.__setattr__(self, "angle_rad", tuple(map(float, ap)))
        object.__setattr__(self, "inductance_H", tuple(tuple(map(float, row)) for row in L))

    def __eq__(self, other):
        return isinstance(other, InductanceTable) and self.to_dict() == other.to_dict()

    def __hash__(self):
        return hash((self.current_A, self.angle_rad, self.inductance_H))

    def to_dict(self):
        return {"current_A": list(self.current_A), "angle_rad": list(self.angle_rad),
                "inductance_H": [list(r) for r in self.inductance_H]}

    def packed(self) -> np.ndarray:
        ci = np.asarray(self.current_A)
        ap = np.asarray(self.angle_rad)
        return np.concatenate([[ci.size, ap.size], ci, ap, np.asarray(self.inductance_H).ravel()])


@kernel
def saturating_inductance(i, phi, L0, r_inf, i_sat, a_phi):
    """h2(i, phi): the parametric inductance map of drive B."""
    x = i / i_sat
    return L0 * (1.0 - a_phi * phi / (0.5 * math.pi)) * (r_inf + (1.0 - r_inf) / (1.0 + x * x))


@kernel
def knot_interval(x, q, off, n):
    """``(k, f)``: x lies a fraction f of the way from knot k to knot k + 1 of the increasing knots
    q[off:off+n], clamped to the first and last interval (f = 0 below the first knot, 1 above the last)."""
    if x <= q[off]:
        return 0, 0.0
    if x >= q[off + n - 1]:
        return n - 2, 1.0
    k = 0
    while q[off + k + 1] < x:
        k += 1
    return k, (x - q[off + k]) / (q[off + k + 1] - q[off + k])


@kernel
def table_inductance(i, phi, q):
    """Bilinear interpolation in a packed InductanceTable q = [n_i, n_phi, I..., PHI..., L(row-major)]."""
    ni = int(q[0])
    nphi = int(q[1])
    lo = 2 + ni + nphi
    ka, fa = knot_interval(abs(i), q, 2, ni)
    kp, fp = knot_interval(phi, q, 2 + ni, nphi)
    l00 = q[lo + ka * nphi + kp]
    l01 = q[lo + ka * nphi + kp + 1]
    l10 = q[lo + (ka + 1) * nphi + kp]
    l11 = q[lo + (ka + 1) * nphi + kp + 1]
    return (1 - fa) * ((1 - fp) * l00 + fp * l01) + fa * ((1 - fp) * l10 + fp * l11)


@kernel
def nonlinear_inductance_drive_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [R, c_M, L0, r_inf, i_sat, a_phi]
    R = p[0]
    k = p[1]
    L = saturating_inductance(i, phi, p[2], p[3], p[4], p[5])
    return k * i, R * i + k * omega, L


@kernel
def table_inductance_drive_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [R, c_M, packed table...]
    R = p[0]
    k = p[1]
    L = table_inductance(i, phi, p[2:])
    return k * i, R * i + k * omega, L


class NonlinearInductanceDrive(Component):
    kind = "drive.B"
    role = "drive"
    Params = NonlinearInductanceDriveParams
    plausible = staticmethod(drive_current_plausible)
    description = "B: nonlinear inductance L = h2(i, phi) (sec. 4.2)"

    @property
    def kernel(self):
        if self.params.inductance_table is None:
            return nonlinear_inductance_drive_kernel
        return table_inductance_drive_kernel

    def param_vector(self):
        q = self.params
        if q.inductance_table is None:
            return np.array([q.resistance_ohm, q.torque_constant_Nm_per_A, q.inductance_H,
                             q.saturated_inductance_ratio, q.saturation_current_A, q.angle_coefficient])
        return np.concatenate([[q.resistance_ohm, q.torque_constant_Nm_per_A], q.inductance_table.packed()])

    def torque_constant(self, phi):
        return np.full_like(np.asarray(phi, float), self.params.torque_constant_Nm_per_A)

    def inductance(self, i, phi):
        q = self.params
        i, phi = np.broadcast_arrays(np.asarray(i, float), np.asarray(phi, float))
        if q.inductance_table is None:
            f = saturating_inductance.py_func
            return f(i, phi, q.inductance_H, q.saturated_inductance_ratio, q.saturation_current_A,
                     q.angle_coefficient)
        packed = q.inductance_table.packed()
        return np.vectorize(lambda a, b: table_inductance.py_func(a, b, packed))(i, phi)


# --------------------------------------------------------------------------------------------- C
@dataclasses.dataclass(frozen=True)
class FluxDriveParams(Params):
    """Model C: torque from the magnet flux Psi(phi) = Psi_hat*sin(phi) (paper sec. 4.3, Table 1).

    k_C = N * Psi_hat with Psi_hat from eq. 13; torque k_C*cos(phi)*i (eq. 14) and back-EMF
    k_C*cos(phi)*omega. ``magnet_permeability`` is Table 1's mu (= 360) used as the dimensionless factor
    mu_A of eqs. 12-13, as the paper evidently did (see docs/model.md).
    """

    resistance_ohm: float = 1.25
    inductance_H: float = 0.02
    ampere_turns: float = 238.0              # N
    remanence_T: float = 1.3                 # B_R
    armature_radius_m: float = 0.014         # r_1
    air_gap_m: float = 0.0004                # delta
    magnet_permeability: float = 360.0       # mu_A
    yoke_angle_rad: float = math.radians(17.0)  # beta
    iron_length_m: float = 0.12              # l_Fe

    def validate(self):
        positive("FluxDriveParams", self, "resistance_ohm", "inductance_H", "ampere_turns", "remanence_T",
                 "armature_radius_m", "air_gap_m", "magnet_permeability", "iron_length_m")
        b = self.yoke_angle_rad
        check("FluxDriveParams", "yoke_angle_rad", b, 0 <= b < math.pi, "an angle in [0, pi) rad")

    @property
    def flux_amplitude_Wb(self) -> float:
        """Psi_hat, eq. 13."""
        b = self.yoke_angle_rad
        den = math.sin(0.5 * (0.5 * math.pi + 0.5 * b)) + self.air_gap_m / self.armature_radius_m * self.magnet_permeability
        return 2.0 * self.remanence_T * self.armature_radius_m * self.iron_length_m / den * math.cos(0.5 * b)

    @property
    def torque_constant_Nm_per_A(self) -> float:
        """k_C = N * Psi_hat: the peak (phi = 0) torque per ampere of eq. 14."""
        return self.ampere_turns * self.flux_amplitude_Wb


@kernel
def flux_drive_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [R, L, k_C]
    k = p[2] * math.cos(phi)
    return k * i, p[0] * i + k * omega, p[1]


class FluxDrive(Component):
    kind = "drive.C"
    role = "drive"
    Params = FluxDriveParams
    kernel = staticmethod(flux_drive_kernel)
    plausible = staticmethod(drive_current_plausible)
    description = "C: extended flux model, torque k_C*cos(phi)*i (sec. 4.3, eqs. 13-14)"

    def param_vector(self):
        q = self.params
        return np.array([q.resistance_ohm, q.inductance_H, q.torque_constant_Nm_per_A])

    def torque_constant(self, phi):
        return self.params.torque_constant_Nm_per_A * np.cos(np.asarray(phi, float))

    def inductance(self, i, phi):
        return np.full(np.broadcast(np.asarray(i), np.asarray(phi)).shape, self.params.inductance_H)


DRIVES = {"A": LinearDrive, "B": NonlinearInductanceDrive, "C": FluxDrive}
