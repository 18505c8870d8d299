"""adversaries/goose."""
