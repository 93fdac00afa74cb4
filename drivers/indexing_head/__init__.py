"""Indexing head (Zaber-style ASCII rotary stage): driver and emulator."""
