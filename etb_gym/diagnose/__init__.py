"""Diagnosis: locate where simulation and recordings disagree, name the physics left out, model it, refit.

    from etb_gym.diagnose import diagnose
    result = diagnose(["rig_run_01.csv"], model="3B", out="diag/")   # report.json, report.md, PNGs, plant

See docs/diagnosis.md for the method and the proof, /work/shared/diagnosis-report.md for report.json.
"""
from .candidates import CANDIDATES, Candidate
from .run import Options, Result, diagnose

__all__ = ["CANDIDATES", "Candidate", "Options", "Result", "diagnose"]
