"""Precision DC voltmeter (SCPI): driver and emulator."""
