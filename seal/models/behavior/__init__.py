"""RCG's behaviour embedding (thesis 7.3): an agent-centric, map-free encoder of full trajectories, a multimodal
reconstruction decoder, a contrastive projection head with a LoRA adapter, and the embedding-space analysis.

Public API (torch-free modules import eagerly; the rest on first use):

* `BehaviorFeatureConfig`, `target_inputs` — what the encoder sees (`seal.models.behavior.features`).
* `safety_labels`, `even_delta` — SafeShift safe / neutral / unsafe labels (eq. 7.1, `seal.models.behavior.labels`).
* `BehaviorConfig`, `BehaviorNet` — the network; `BehaviorModel` — inference, the unsafe cache, save / load.
* `BehaviorTrainConfig`, `pretrain`, `finetune` — the two training stages (eq. 7.5, eq. 7.6).
"""

from __future__ import annotations

import importlib
from typing import Any

from seal.models.behavior.features import BehaviorFeatureConfig, target_inputs
from seal.models.behavior.labels import NEUTRAL, SAFE, SAFETY_CLASSES, UNSAFE, even_delta, safety_labels

_LAZY = {
    "BehaviorConfig": "seal.models.behavior.network",
    "BehaviorNet": "seal.models.behavior.network",
    "BehaviorModel": "seal.models.behavior.model",
    "BehaviorFileError": "seal.models.behavior.model",
    "BehaviorTrainConfig": "seal.models.behavior.train",
    "pretrain": "seal.models.behavior.train",
    "finetune": "seal.models.behavior.train",
}

__all__ = ["BehaviorFeatureConfig", "target_inputs", "safety_labels", "even_delta", "SAFE", "NEUTRAL", "UNSAFE",
           "SAFETY_CLASSES", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'seal.models.behavior' has no attribute {name!r}")
