"""Vibration-table crank servo: a CiA 402 drive over CANopen (driver and emulator)."""
