#!/usr/bin/env python
"""Blind proof of the diagnosis tool: a thin wrapper of ``etb_gym.diagnose.proof`` (``etb-gym prove``)."""
import sys

from etb_gym.diagnose.proof import main

if __name__ == "__main__":
    sys.exit(main())
