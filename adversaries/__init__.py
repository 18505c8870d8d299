"""Adversary generators: given a scenario and its last K ego roll-outs, the adversary's next behaviour."""

from adversaries.base import AdversaryGenerator, Generation, available_generators, make_generator, register
from adversaries.replay import ReplayGenerator

__all__ = [
    "AdversaryGenerator",
    "Generation",
    "ReplayGenerator",
    "available_generators",
    "make_generator",
    "register",
]
