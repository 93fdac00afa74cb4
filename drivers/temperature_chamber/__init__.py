"""Temperature chamber (EI-Bisynch ASCII): driver and emulator."""
