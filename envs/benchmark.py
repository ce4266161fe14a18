"""Steps per second of the ETB envs: a thin wrapper of the one speed harness, etb_gym.speed (``etb-gym speed``).

    python -m etb_gym.envs.benchmark --id ETB-1A-v0 --n 1 256 --seconds 3 --compare CartPole-v1

Takes the harness's options (``--help``); ``--id``, ``--n``, ``--seconds``, ``--compare`` and ``--threads``
keep their meaning.
"""
from __future__ import annotations

import sys

from etb_gym.speed import main

if __name__ == "__main__":
    sys.exit(main())
