"""Digital twin of the station (physics.md): table motion, instrument, counter windows, raw streams."""

from models.config import EFFECTS, TwinConfig, TwinConfigError, default_twin

__all__ = ["EFFECTS", "TwinConfig", "TwinConfigError", "default_twin"]
