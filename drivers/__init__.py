"""Device drivers of the station; drivers/sim holds the protocol-level emulators."""
