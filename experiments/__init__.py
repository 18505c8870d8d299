"""Experiments: ego training, evaluation protocol, reports, benchmarks, YAML presets, the demo."""
