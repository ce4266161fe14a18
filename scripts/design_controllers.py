#!/usr/bin/env python
"""Controller design report (thin wrapper of ``etb-gym design``, i.e. :func:`etb_gym.controllers.design_report.main`).

    python scripts/design_controllers.py --help
"""
import sys

from etb_gym.controllers.design_report import main

if __name__ == "__main__":
    sys.exit(main())
