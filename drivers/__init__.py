"""The station's devices: one package per device; transports, the simulated world and the station assembly."""
