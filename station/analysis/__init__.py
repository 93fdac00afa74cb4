"""Calibration analysis: window means, regressors, least squares, evaluation."""
