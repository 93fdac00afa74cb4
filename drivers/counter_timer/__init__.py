"""Counter/timer board timing integer-pulse windows: driver and emulator."""
