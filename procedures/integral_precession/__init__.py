"""Seed 000: integral precession calibration of a PIGA on the linear vibration table (procedures, analysis, reports)."""
