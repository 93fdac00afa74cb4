"""Digital twin of the station (physics.md): table motion, instrument, counter windows, raw streams."""

from models.config import TwinConfig, TwinConfigError, default_twin
from models.effects import EFFECTS

__all__ = ["EFFECTS", "TwinConfig", "TwinConfigError", "default_twin"]
