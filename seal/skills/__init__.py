"""SEAL skills (thesis 6.3.2, after ReSkill): demonstrations as 10-step (observation, action) windows, a skill VAE
with a closed-loop decoder, state-conditioned RealNVP priors for benign and adversarial skills, and the skill
policy that samples a skill every horizon and decodes it step by step.

Core: torch and numpy only; the simulator-side parts (demonstration roll-outs, the env behaviour) live in
``envs.demonstrations`` and ``envs.skill_behavior``. Names resolve lazily, so ``seal.skills.demos`` (numpy only)
loads without torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "Demonstrations": "seal.skills.demos",
    "WindowSpec": "seal.skills.demos",
    "Windows": "seal.skills.demos",
    "label_windows": "seal.skills.demos",
    "SkillVAE": "seal.skills.vae",
    "VAEConfig": "seal.skills.vae",
    "ConditionalRealNVP": "seal.skills.realnvp",
    "RealNVPConfig": "seal.skills.realnvp",
    "SkillPolicy": "seal.skills.policy",
    "load_skill_models": "seal.skills.io",
    "save_model": "seal.skills.io",
}

__all__ = list(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'seal.skills' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
