"""PIGA calibration station controller: digital twin, procedure engine, store and analysis."""

import importlib

__version__ = "0.1.0"


def __getattr__(name: str):
    """`station.open_store` (station.notebook, the notebook facade) is loaded by name on first use, so that
    `import station` stays light (no pandas) and the core imports nothing above it."""
    if name == "open_store":
        return importlib.import_module("station.notebook").open_store
    raise AttributeError(f"module 'station' has no attribute {name!r}")
