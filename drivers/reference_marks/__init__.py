"""Reference marks and frequency monitor: driver and emulator."""
