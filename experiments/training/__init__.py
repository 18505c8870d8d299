"""experiments/training."""
