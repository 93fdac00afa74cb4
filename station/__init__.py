"""PIGA calibration station controller: digital twin, procedure engine, store and analysis."""

__version__ = "0.1.0"


def __getattr__(name: str):
    """`station.open_store` is imported on first use, so that `import station` stays light (no pandas)."""
    if name == "open_store":
        from station.notebook import open_store

        return open_store
    raise AttributeError(f"module 'station' has no attribute {name!r}")
