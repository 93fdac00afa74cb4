"""PIGA electronics and its angle servo's digital offset: driver and emulator."""
