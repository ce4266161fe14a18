"""The coarse scan does not start a candidate's fit where its effect is switched off (fit.scan_start's ``off``)."""
import numpy as np

from etb_gym.diagnose import fit as F
from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.model import Spec
from etb_gym.plant import make_plant


def test_off_value_is_the_play_at_zero():
    spec = Spec(make_plant("3B")).with_candidate(CANDIDATES["backlash"])
    k = len(spec.params) - 2                      # the play, the candidate's first parameter
    p = spec.params[k][1]
    assert p.name == "play_rad"
    assert F.off_value(spec, k) == (0.0 - p.init) / p.scale
    assert F.off_value(spec, k + 1) == 0.0         # the closing share: off at its start, 1
    assert F.off_value(spec, 0) is None            # a nominal parameter has no off value


def _fun(best_at):
    def fun(x):
        fun.failure = None
        return np.array([x[0] - best_at, 0.1 * x[0]])
    fun.failure = None
    return fun


def test_the_scan_skips_the_off_point():
    """A scan point at the candidate switched off (the current model itself: a play at 0 that the
    local fit cannot leave, its first order a preload the calibration carries) is left to fit(), which fits from
    it and from the best of the others when it wins."""
    lo, hi = np.array([-4.0 / 3.0]), np.array([56.0 / 3.0])
    x0 = np.zeros(1)
    fun = _fun(lo[0])
    r0 = fun(x0)
    x, _, _ = F.scan_start(fun, x0, r0, 0, lo, hi)
    assert abs(x[0] - lo[0]) < 1e-6                          # without ``off`` the bound (off) wins
    x, _, n = F.scan_start(fun, x0, r0, 0, lo, hi, off=float(lo[0]))
    assert abs(x[0] - lo[0]) > 0.1 and n == len(F.scan_offsets(lo[0] + 1e-9, hi[0] - 1e-9)) - 1
