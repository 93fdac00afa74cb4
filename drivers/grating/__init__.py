"""Absolute grating read head: driver and emulator."""
