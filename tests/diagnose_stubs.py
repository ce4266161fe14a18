"""Stand-ins for the diagnosis's fits in unit tests of the naming rules (no simulation): a current model, a
model with one more parameter (an alternative family) and generic tables with given held-out error and terms."""
import numpy as np

from etb_gym.diagnose import unmodelled as U


class Spec:
    candidates = ()


class Cur:
    spec = Spec()
    x = np.zeros(3)


class Alt(Cur):
    x = np.zeros(4)


def generic(terms, heldout: float = 1.0, periodic: bool = False) -> U.Generic:
    """Generic tables whose significant terms are ``terms`` (angle table periodic with 20 deg if ``periodic``)."""
    shape = {"significant_terms": terms, "angle": {"periodic": periodic, "period_deg": 20.0 if periodic else None}}
    return U.Generic(None, [], [], heldout, {}, {t: 1.0 for t in terms}, 0.01, shape)


def swing_data(centre_deg: float, amplitude_deg: float, name: str = "swing.csv"):
    """3 s at 1 kHz of a plate swinging centre +- amplitude deg at 0.5 Hz under 2 V (no current recorded),
    prepared for the diagnosis at 12 V: where a table's knots are visited and where not."""
    from etb_gym.diagnose.model import prepare
    from etb_gym.recordings import Recording
    t = np.arange(3000) * 1e-3
    ang = centre_deg + amplitude_deg * np.sin(2 * np.pi * 0.5 * t)
    rec = Recording(name=name, t_s=t, voltage_V=np.full(t.size, 2.0), angle_deg=ang, current_A=None,
                    supply_V=None)
    return prepare([rec], 12.0)
