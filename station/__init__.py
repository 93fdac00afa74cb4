"""PIGA calibration station controller: digital twin, procedure engine, store and analysis."""

__version__ = "0.1.0"
