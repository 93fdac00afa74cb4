"""Seed 001: eight-point tumble calibration of a pendulous accelerometer in the gravity field."""
