"""experiments/evaluation."""
