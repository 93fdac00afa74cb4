"""Electrodynamic shaker's vibration controller: driver and emulator."""
