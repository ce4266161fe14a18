#!/usr/bin/env python
"""Regenerate analogues of the paper's figures: ``etb-gym reproduce`` (etb_gym.paper), kept for old commands."""
import sys

from etb_gym.paper import main

if __name__ == "__main__":
    sys.exit(main(prog="reproduce_paper.py"))
