"""adversaries/cat."""
