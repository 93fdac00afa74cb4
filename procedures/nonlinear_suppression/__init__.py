"""Seed 004: suppression of the PIGA's nonlinear error by the angle servo's offset and a mass removal."""
