#!/usr/bin/env python
"""Controller benchmark (thin wrapper of ``etb-gym benchmark``, i.e. :func:`etb_gym.benchmark_cli.main`).

    python scripts/benchmark.py --help
"""
import sys

from etb_gym.benchmark_cli import main

if __name__ == "__main__":
    sys.exit(main())
