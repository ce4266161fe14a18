"""No crash on any input the recording format accepts, with any valid plant file (issue 15): odd but valid
recordings go through the whole diagnosis and end in a report, or in a clear one-sentence error naming what
failed; never a traceback from deep inside, never an "internal error"."""
import contextlib
import functools
import io
import math
import re
import warnings

import numpy as np
import pytest

from etb_gym.diagnose import cli
from etb_gym.diagnose.run import Options, diagnose
from etb_gym.diagnose.synthetic import make_recording, nameplate_file_plant, random_nameplate
from etb_gym.plant import make_plant
from etb_gym.plantfile import save_plant
from etb_gym.recordings import save_recording, validate

VERDICTS = {"match", "explained", "partly_explained", "unexplained", "outside_catalogue"}
FAST = dict(jobs=1, progress=False, verbose=False, max_effects=1,
            candidates=("torque_constant_error", "sensor_offset_gain"))


def columns(name, t, v, a, i=None, sup=None):
    cols = {"time_s": t, "voltage_V": v, "angle_deg": a}
    if i is not None:
        cols["current_A"] = i
    if sup is not None:
        cols["supply_V"] = sup
    return validate(cols, source=name, name=name)     # what the recording format accepts


ODD_CASES = ("shortest accepted (0.5 s)", "zero voltage, plate at rest", "reading exactly constant",
             "pinned at the open stop", "pinned below the closed stop", "saturated duty only (+-12 V)",
             "extreme noise (3 deg, coloured)", "several recordings, open and closed",
             "duty and a varying supply, no current", "time starting at 1000 s", "sample period 0.2 ms",
             "sample period 5 ms")


@functools.cache
def odd_recordings_by_case():
    """{case: (recordings, plant or None)}, built once per test process when a test first asks (not at
    collection: both xdist workers collect every module, and the simulations compiled 3B's stepper in each)."""
    cases = {case: (recs, plant) for case, recs, plant in odd_recordings()}
    assert tuple(cases) == ODD_CASES, tuple(cases)
    return cases


def odd_recordings():
    """(case, recordings, plant or None): each accepted by recordings.validate."""
    rng = np.random.default_rng(11)
    p3 = make_plant("3B", substeps=10)
    n = 501
    t = np.arange(n) * 1e-3
    noise = 0.01 * rng.normal(size=n)
    yield "shortest accepted (0.5 s)", [make_recording(p3, rng, duration_s=0.501, name="short.csv")], None
    yield "zero voltage, plate at rest", [columns("zero.csv", t, np.zeros(n), 7.0 + noise)], None
    yield "reading exactly constant", [columns("const.csv", t, np.zeros(n), np.full(n, 7.0))], None
    yield "pinned at the open stop", [columns("open.csv", t, np.full(n, 12.0), 90.0 + noise)], None
    yield "pinned below the closed stop", [columns("closed.csv", t, np.full(n, -4.0), -3.0 + noise)], None
    r = make_recording(p3, rng, duration_s=0.6, name="sat.csv")
    yield "saturated duty only (+-12 V)", [columns("sat.csv", r.t_s, np.where(r.voltage_V >= 0, 12.0, -12.0),
                                                   r.angle_deg, r.current_A)], None
    yield "extreme noise (3 deg, coloured)", [make_recording(p3, rng, duration_s=0.6, noise_deg=3.0, colour=0.9,
                                                             name="noisy.csv")], None
    yield "several recordings, open and closed", [make_recording(p3, rng, duration_s=0.6, name="a.csv"),
                                                  make_recording(p3, rng, duration_s=0.8, closed=True,
                                                                 name="b.csv")], None
    yield "duty and a varying supply, no current", [columns("sup.csv", r.t_s, 0.9 * r.voltage_V, r.angle_deg,
                                                            None, 13.0 + np.sin(20 * r.t_s))], None
    yield "time starting at 1000 s", [columns("late.csv", r.t_s + 1000.0, r.voltage_V, r.angle_deg, r.current_A)], None
    for dt in (2e-4, 5e-3):
        pl = make_plant("3B", control_period_s=dt, substeps=10)
        yield f"sample period {dt * 1e3:g} ms", [make_recording(pl, rng, duration_s=max(0.6, 250 * dt),
                                                               name=f"dt{dt}.csv")], None


def check_outcome(fn):
    """Either a report with a known verdict, or a ValueError whose message is a sentence naming the problem."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = fn()
    except ValueError as e:
        msg = str(e)
        assert msg and "internal error" not in msg and "array(" not in msg and "Traceback" not in msg, msg
        return None
    rep = res.report
    assert rep["verdict"] in VERDICTS, rep["verdict"]
    assert math.isfinite(rep["rms_before_deg"]) and math.isfinite(rep["rms_after_deg"])
    assert set(rep["loop"].values()) <= {"open", "closed"}
    return res


@pytest.mark.parametrize("case", ODD_CASES)
def test_odd_but_valid_recordings_end_in_a_report_or_a_clear_error(case):
    recs, plant = odd_recordings_by_case()[case]
    check_outcome(lambda: diagnose(recs, options=Options(plant=plant, **FAST)))


@pytest.mark.parametrize("seed", [3, 4])
def test_cli_on_a_random_nameplate_plant_file_writes_a_report(tmp_path, seed):
    """``etb-gym diagnose --plant FILE`` with a random nameplate (friction and spring 10-20 % off), open and
    closed loop: exit 0 and a report, or exit 3 with a one-line reason that is not an internal error."""
    rng = np.random.default_rng(seed)
    truth = random_nameplate(rng, substeps=20)
    file_plant = nameplate_file_plant(truth, rng)
    pf = tmp_path / "plant.toml"
    save_plant(file_plant, pf)
    from etb_gym.diagnose.proof import _controller
    recs = [make_recording(truth, rng, duration_s=0.8, name="o.csv"),
            make_recording(truth, rng, duration_s=0.8, closed=True, controller=_controller(file_plant), name="c.csv")]
    paths = [str(save_recording(r, tmp_path / r.name)) for r in recs]
    err = io.StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        code = cli.main(paths + ["--plant", str(pf), "--out", str(tmp_path / "out"), "--jobs", "1", "--quiet",
                                 "--max-effects", "1", "--candidates", "torque_constant_error", "shaft_flux_loss"])
    msg = err.getvalue()
    assert code in (0, 3), (code, msg)
    assert "internal error" not in msg and "Traceback" not in msg, msg
    assert (tmp_path / "out" / "report.json").exists()
    if code == 0:
        import json
        rep = json.loads((tmp_path / "out" / "report.json").read_text())
        assert rep["verdict"] in VERDICTS
        assert re.fullmatch(r"open|closed", rep["loop"]["c.csv"])
