"""seal/core."""
