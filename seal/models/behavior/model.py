"""`BehaviorModel`: a trained behaviour embedding for inference, with its prototypes and unsafe cache.

The unsafe cache ``V_unsafe [N_u, proj_dim]`` (thesis 7.4) holds the embeddings of the behaviours labelled unsafe
(everyday unsafe behaviours and the crash set's unsafe agents), computed once when the model is fitted and saved
with it, so RCG scoring is a nearest-neighbour look-up.

File format: ``torch.save`` of a dict (format tag, version, config, state dict, prototypes, cache, JSON-safe info)
read back with ``torch.load(weights_only=True)``, plus a readable ``<name>.json`` of config and info.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.errors import SealError
from seal.core.weights_file import check_header, read_weights_file
from seal.models.behavior.features import BehaviorInputs, shared_frame_inputs, target_inputs
from seal.models.behavior.losses import Prototypes
from seal.models.behavior.network import BehaviorConfig, BehaviorNet

FORMAT = "seal-behavior-model"
FORMAT_VERSION = 1
BATCH = 512


class BehaviorFileError(SealError, ValueError):
    """A behaviour model file is unreadable or not a behaviour model; the message names the file."""


class BehaviorModel:
    """A behaviour embedding (see the module docstring).

    Args:
        config: architecture.
        net: the network (a fresh one when None).
        prototypes: class prototypes after training (None before).
        unsafe_cache: ``[N_u, proj_dim]`` float32 unsafe embeddings (None before `set_unsafe_cache`).
        lora: whether embeddings include the LoRA adapter (False for models that were never fine-tuned; the
            adapter is then the identity anyway).
        info: JSON-safe metadata saved with the model.
    """

    def __init__(self, config: BehaviorConfig | None = None, net: BehaviorNet | None = None,
                 prototypes: Prototypes | None = None, unsafe_cache: np.ndarray | None = None, lora: bool = True,
                 info: dict[str, Any] | None = None) -> None:
        self.config = config or BehaviorConfig()
        self.net = net if net is not None else BehaviorNet(self.config)
        self.net.eval()
        self.prototypes = prototypes
        self.unsafe_cache = None if unsafe_cache is None else np.asarray(unsafe_cache, dtype=np.float32)
        self.lora = bool(lora)
        self.info = dict(info or {})

    @torch.no_grad()
    def embed(self, inputs: BehaviorInputs) -> np.ndarray:
        """``v [P, proj_dim]`` float32 unit embeddings of the targets of ``inputs``."""
        out = []
        for i in range(0, len(inputs), BATCH):
            rows = slice(i, i + BATCH)
            z = self.net.encode(torch.from_numpy(inputs.agents[rows]), torch.from_numpy(inputs.mask[rows]))
            out.append(self.net.project(z, lora=self.lora).numpy())
        return np.concatenate(out) if out else np.zeros((0, self.config.proj_dim), np.float32)

    def embed_tracks(self, tracks: np.ndarray, target: np.ndarray) -> np.ndarray:
        """``v [P, proj_dim]`` of agent ``target[p]`` in scene ``tracks[p]`` (``[P, A, N_STEPS, 8]``)."""
        return self.embed(target_inputs(tracks, target, self.config.features))

    def embed_scenes(self, bank: np.ndarray, scenes: np.ndarray, target_col: int) -> np.ndarray:
        """``v [P, proj_dim]`` of the target (column ``target_col``) of scenes assembled from a bank of tracks whose
        target has one pose at the current step (`seal.models.behavior.features.shared_frame_inputs`)."""
        return self.embed(shared_frame_inputs(bank, scenes, target_col, self.config.features))

    def set_unsafe_cache(self, embeddings: np.ndarray) -> None:
        self.unsafe_cache = np.asarray(embeddings, dtype=np.float32).reshape(-1, self.config.proj_dim)

    def unsafe_prototype(self) -> np.ndarray:
        """``[proj_dim]`` the unsafe class centroid (for the prototype-distance ablation of Table 7.4)."""
        from seal.models.behavior.labels import UNSAFE

        if self.prototypes is None or not bool(self.prototypes.present[UNSAFE]):
            raise ValueError("behaviour model: no unsafe prototype (the model was saved without training)")
        return self.prototypes.centroids[UNSAFE].numpy().astype(np.float32)

    # ------------------------------------------------------------------------------------------------- files
    def save(self, path: str | Path) -> Path:
        path = Path(path)
        protos = None if self.prototypes is None else {
            "centroids": self.prototypes.centroids, "phi": self.prototypes.phi, "present": self.prototypes.present}
        state = {
            "format": FORMAT, "format_version": FORMAT_VERSION, "config": self.config.to_dict(),
            "state_dict": self.net.state_dict(), "prototypes": protos, "lora": self.lora,
            "unsafe_cache": None if self.unsafe_cache is None else torch.from_numpy(self.unsafe_cache),
            "info": self.info,
        }
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write_bytes(path, buf.getvalue())
        atomic_write_json(path.with_suffix(".json"), {"config": self.config.to_dict(), "info": self.info})
        return path

    @classmethod
    def load(cls, path: str | Path) -> BehaviorModel:
        path = Path(path)
        state = read_weights_file(path, "behaviour model file", "seal fit behavior", BehaviorFileError)
        check_header(state, str(path), FORMAT, FORMAT_VERSION,
                     ("config", "state_dict", "prototypes", "lora", "unsafe_cache", "info"), BehaviorFileError,
                     " (write one with `seal fit behavior`)")
        try:
            config = BehaviorConfig.from_dict(state["config"], f"{path}: field 'config'")
            net = BehaviorNet(config)
            net.load_state_dict(state["state_dict"])
        except (TypeError, ValueError, RuntimeError) as exc:
            raise BehaviorFileError(f"{path}: the stored network does not load ({exc})") from None
        p = state["prototypes"]
        protos = None if p is None else Prototypes(p["centroids"], p["phi"], p["present"])
        cache = state["unsafe_cache"]
        return cls(config, net, protos, None if cache is None else cache.numpy(), bool(state["lora"]),
                   dict(state["info"]))
