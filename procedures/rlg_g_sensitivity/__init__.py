"""Seed 002: g-sensitive misalignment calibration of a strapdown IMU's RLG triad in linear vibration."""
