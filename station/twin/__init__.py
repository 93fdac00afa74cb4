"""Digital twin of the station (physics.md): table motion, instrument, counter windows, raw streams."""

from station.twin.config import TwinConfig, TwinConfigError, default_twin
from station.twin.effects import EFFECTS

__all__ = ["EFFECTS", "TwinConfig", "TwinConfigError", "default_twin"]
