"""experiments/pipeline."""
