"""Station constants of physics.md (seed 000, latitude 39.94 deg, altitude 2.7 m)."""

G_MPS2 = 9.8016093
EARTH_RATE_RADPS = 7.292115e-5
LATITUDE_DEG = 39.94
A0_M = 0.03
PULSES_PER_REV = 16384
TIMER_TICK_S = 50e-9
GRATING_RATE_HZ = 5000.0
