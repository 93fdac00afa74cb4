"""The station's applications: the `station` command, the console, the controller and its control channel."""
