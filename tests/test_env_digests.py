"""Behaviour lock: env trajectories (single and native vector env, every observation, sensing and randomization
option) hash to the digests recorded in tests/data/env_digests.json (written by ``tests/env_digests.py``).
A refactor must leave them bit-identical; a change of behaviour on purpose rewrites the file (see that module)."""
import json

import pytest

from env_digests import DATA, digests
from etb_gym.jit import HAVE_NUMBA


def test_quick_digests_unchanged():
    ref = json.loads(DATA.read_text())["quick"]
    now = digests(quick=True)
    differ = sorted(k for k in ref if now.get(k) != ref[k])
    assert set(now) == set(ref), "the case list changed: rewrite with python tests/env_digests.py --write"
    assert not differ, (f"{len(differ)} of {len(ref)} env trajectories changed: {differ}. If intended, rewrite "
                        "tests/data/env_digests.json with python tests/env_digests.py --write and say why")


@pytest.mark.skipif(not HAVE_NUMBA, reason="the full record includes the multi-threaded vector env")
def test_digest_record_covers_all_models_and_fast_equals_plain():
    full = json.loads(DATA.read_text())["full"]
    assert sum(k.startswith("vector ") for k in full) >= 30 and sum(k.startswith("single ") for k in full) >= 20
    assert all(v is True for k, v in full.items() if k.endswith("fast == plain") or k.endswith("round trip"))
