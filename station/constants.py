"""Station constants of physics.md (seed 000, latitude 39.94 deg, altitude 2.7 m)."""

G_MPS2 = 9.8016093
EARTH_RATE_RADPS = 7.292115e-5
LATITUDE_DEG = 39.94
A0_M = 0.03
PULSES_PER_REV = 16384
TIMER_TICK_S = 50e-9
GRATING_RATE_HZ = 5000.0

# Seed 000's simulated PIGA (physics.md, instrument rate model): the nominal instrument that planning,
# the twin and the seed-000 procedures assume unless told otherwise.
K0_RADPS = 1.5e-4
KZ_RADPS_PER_G = 0.56
KZZ_RADPS_PER_G2 = 6.0e-6
KY_RADPS_PER_G2 = 5.0e-6
K3_RADPS_PER_G3 = 7.0e-7

# Seed 000 Table 4: the vibration table's frequency stability, sigma_f / f.
FREQ_STABILITY_MAX = 5.0e-4
