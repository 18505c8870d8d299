"""Adversary generators: given a scenario and its last K ego roll-outs, the adversary's next behaviour."""

from seal.adversaries.base import AdversaryGenerator, Generation, available_generators, make_generator, register
from seal.adversaries.cat.generator import CATGenerator
from seal.adversaries.replay import ReplayGenerator
from seal.adversaries.rule import RuleGenerator

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
