"""The panel's HTTP and WebSocket endpoints, one module per part of the panel."""
