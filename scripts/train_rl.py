#!/usr/bin/env python
"""Train a Stable-Baselines3 agent on an ETB env: ``etb-gym train`` (etb_gym.rl.train), kept for old commands."""
import sys

from etb_gym.rl.train import main

if __name__ == "__main__":
    sys.exit(main(prog="train_rl.py"))
