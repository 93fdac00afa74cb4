"""Procedure engine: procedures are generators of steps; one engine validates, estimates and runs them."""
