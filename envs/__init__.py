"""Gymnasium environments on highway-env roads: ScenarioEnv (the Gymnasium adapter) and MultiAgentSim on one
simulation core (`seal.envs.sim_core`), observation, behaviours, heuristic driver, rendering and base-scenario
generation.

Importing ``envs`` registers ``seal/Scenario-v0`` (entry point ``seal.envs.scenario_env:ScenarioEnv``) with
Gymnasium; heavy modules load only when used (``seal.envs.ScenarioEnv`` is resolved lazily).
"""

from __future__ import annotations

from typing import Any

import gymnasium

ENV_ID = "seal/Scenario-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="seal.envs.scenario_env:ScenarioEnv")

_LAZY = {
    "ScenarioEnv": "seal.envs.scenario_env",
    "DEFAULT_CONFIG": "seal.envs.scenario_env",
    "Rollout": "seal.envs.rollout",
    "AdversaryBehavior": "seal.envs.behaviors",
    "BehaviorOutput": "seal.envs.behaviors",
    "ReplayBehavior": "seal.envs.behaviors",
    "TrackingBehavior": "seal.envs.behaviors",
    "PolicyBehavior": "seal.envs.behaviors",
    "HeuristicDriver": "seal.envs.heuristic",
    "ObservationBuilder": "seal.envs.observation",
    "AgentState": "seal.envs.kinematics",
    "REWARD_TERMS": "seal.envs.sim_core",
    "MultiAgentSim": "seal.envs.multi_agent",
}

__all__ = ["ENV_ID", *_LAZY]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'envs' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
