"""A second PIGA on the indexing head with a counter channel of its own (seed 003)."""
