"""pyserial URL handlers of the station (pyserial imports `<package>.protocol_<scheme>`); see devices.sim_serial."""
