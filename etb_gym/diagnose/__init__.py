"""Diagnosis tool: where and why recordings disagree with the model (see docs/diagnosis.md)."""
