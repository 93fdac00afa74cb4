"""Simulated devices that speak the real protocols over real transports, driven by the twin."""
