"""Adversary generators: given a scenario and its last K ego roll-outs, the adversary's next behaviour."""

from adversaries.base import AdversaryGenerator, Generation, available_generators, make_generator, register
from adversaries.cat import CATGenerator
from adversaries.replay import ReplayGenerator
from adversaries.rule import RuleGenerator

__all__ = [
    "AdversaryGenerator",
    "CATGenerator",
    "Generation",
    "ReplayGenerator",
    "RuleGenerator",
    "available_generators",
    "make_generator",
    "register",
]
