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
