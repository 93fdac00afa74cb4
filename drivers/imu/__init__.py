"""Strapdown IMU streaming increments over RS-422: driver and emulator."""
