"""SEAL skills (thesis 6.3.2, after ReSkill): demonstrations as 10-step (observation, action) windows, a skill VAE
with a closed-loop decoder, state-conditioned RealNVP priors for benign and adversarial skills, and the skill
policy that samples a skill every horizon and decodes it step by step.

Core: torch and numpy only; the simulator-side parts (demonstration roll-outs, the env behaviour) live in
``seal.models.skills.demonstrations`` and ``seal.envs.skill_behavior``. Names resolve lazily, so
``seal.models.skills.demos`` (numpy only)
loads without torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "Demonstrations": "seal.models.skills.demos",
    "WindowSpec": "seal.models.skills.demos",
    "Windows": "seal.models.skills.demos",
    "label_windows": "seal.models.skills.demos",
    "SkillVAE": "seal.models.skills.vae",
    "VAEConfig": "seal.models.skills.vae",
    "ConditionalRealNVP": "seal.models.skills.realnvp",
    "RealNVPConfig": "seal.models.skills.realnvp",
    "SkillPolicy": "seal.models.skills.policy",
    "load_skill_models": "seal.models.skills.io",
    "save_model": "seal.models.skills.io",
}

__all__ = list(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'seal.models.skills' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
