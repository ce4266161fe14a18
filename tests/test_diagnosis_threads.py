"""The diagnosis runs its linear algebra on one BLAS thread (diagnose/threads.py)."""
import numpy as np
import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")


def _blas_threads():
    return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]


def test_one_blas_thread_limits_and_restores():
    from etb_gym.diagnose.threads import one_blas_thread
    np.linalg.solve(np.eye(3), np.ones(3))          # BLAS loaded
    before = _blas_threads()
    assert before
    with one_blas_thread():
        assert _blas_threads() == [1] * len(before)
    assert _blas_threads() == before


def test_diagnose_works_inside_the_limit(monkeypatch):
    """Seen from inside the pipeline (the integrator step is chosen after the data is prepared)."""
    from etb_gym.diagnose import run
    from etb_gym.diagnose.synthetic import make_recording
    from etb_gym.plant import make_plant

    seen = []

    class Stop(Exception):
        pass

    def spy(*a, **k):
        seen.append(_blas_threads())
        raise Stop

    monkeypatch.setattr(run, "choose_substeps", spy)
    rec = make_recording(make_plant("3B"), np.random.default_rng(0), duration_s=1.0, name="r.csv")
    with pytest.raises(Stop):
        run.diagnose([rec], progress=False, verbose=False, jobs=1)
    assert seen and seen[0] and all(n == 1 for n in seen[0])
