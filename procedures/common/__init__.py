"""What the methods share: least squares with their uncertainties."""
