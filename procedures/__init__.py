"""The procedure library: one module per calibration method."""
