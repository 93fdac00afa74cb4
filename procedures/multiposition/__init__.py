"""Static multiposition calibration on the indexing head in the gravity field (seed 003)."""
