#!/usr/bin/env python
"""Thin wrapper of the speed harness etb_gym.speed (``etb-gym speed``): see ``--help`` and docs/speed.md."""
import sys

from etb_gym.speed import main

if __name__ == "__main__":
    sys.exit(main())
