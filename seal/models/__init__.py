"""seal/models."""
