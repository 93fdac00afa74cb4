"""Electronic gradiometer on the table top: driver and emulator."""
