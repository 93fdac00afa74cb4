"""FastAPI web panel: live monitoring, history and authenticated control."""
