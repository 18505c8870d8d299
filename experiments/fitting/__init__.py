"""experiments/fitting."""
