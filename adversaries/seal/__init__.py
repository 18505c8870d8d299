"""adversaries/seal."""
