"""Saving and loading skill models: one file per model (``torch.save`` of a dict with the format tag, the config,
the state dict and a JSON-safe info dict), read back with ``torch.load(weights_only=True)``.

A skills folder written by ``seal fit skills`` holds `VAE_FILE` and one prior file per class (`prior_file`).
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from seal.core.atomic import atomic_write_bytes
from seal.core.weights_file import check_header, read_weights_file
from seal.models.skills.realnvp import ConditionalRealNVP, RealNVPConfig
from seal.models.skills.vae import SkillVAE, VAEConfig

FORMAT = "seal-skill-model"
FORMAT_VERSION = 1
VAE_FILE = "vae.pt"
PRIOR_CLASSES = ("benign", "adversarial")


class SkillModelError(ValueError):
    """A skill model file is unreadable or not a skill model; the message names the file and the field."""


def prior_file(name: str) -> str:
    """File name of the prior of class ``name`` (``benign`` or ``adversarial``)."""
    if name not in PRIOR_CLASSES:
        raise ValueError(f"unknown prior {name!r}; choose from {PRIOR_CLASSES}")
    return f"prior_{name}.pt"


def save_model(model: SkillVAE | ConditionalRealNVP, path: str | os.PathLike[str],
               info: dict[str, Any] | None = None) -> None:
    """Write ``model`` atomically with its config and ``info`` (JSON-serialisable)."""
    kind = "vae" if isinstance(model, SkillVAE) else "prior"
    state = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "config": model.config.to_dict(),
        "state_dict": {k: v.detach().clone() for k, v in model.state_dict().items()},
        # JSON round trip: only types torch.load(weights_only=True) accepts.
        "info": json.loads(json.dumps(info or {}, default=str)),
    }
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(path, buf.getvalue())


def load_model(path: str | os.PathLike[str], kind: str | None = None) -> tuple[SkillVAE | ConditionalRealNVP,
                                                                                dict[str, Any]]:
    """Model and info from a file written by `save_model`; ``kind`` (``vae`` / ``prior``) is checked if given."""
    path = Path(path)
    state = read_weights_file(path, "skill model file", "seal fit skills", SkillModelError)
    where = f"skill model file {path}"
    check_header(state, where, FORMAT, FORMAT_VERSION, ("config", "state_dict"), SkillModelError)
    found = state.get("kind")
    if found not in ("vae", "prior") or (kind is not None and found != kind):
        raise SkillModelError(f"{where}: field 'kind' is {found!r}, expected {kind or 'vae or prior'!r}")
    try:
        if found == "vae":
            model: SkillVAE | ConditionalRealNVP = SkillVAE(VAEConfig.from_dict(state["config"], where))
        else:
            model = ConditionalRealNVP(RealNVPConfig.from_dict(state["config"], where))
        model.load_state_dict(state["state_dict"])
    except (RuntimeError, TypeError, ValueError) as exc:
        raise SkillModelError(f"{where}: field 'state_dict' does not fit field 'config' ({exc})") from None
    model.eval()
    return model, dict(state.get("info", {}))


@dataclass
class SkillModels:
    """A skills folder: the VAE and the priors by class name, with their info dicts."""

    vae: SkillVAE
    priors: dict[str, ConditionalRealNVP]
    info: dict[str, dict[str, Any]] = field(default_factory=dict)


def load_skill_models(folder: str | os.PathLike[str], priors: tuple[str, ...] = PRIOR_CLASSES) -> SkillModels:
    """Load `VAE_FILE` and the requested priors from ``folder``; checks that their dimensions agree."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"skills folder {folder} not found (train with `seal fit skills`)")
    vae, vae_info = load_model(folder / VAE_FILE, "vae")
    assert isinstance(vae, SkillVAE)
    loaded: dict[str, ConditionalRealNVP] = {}
    info = {"vae": vae_info}
    for name in priors:
        prior, prior_info = load_model(folder / prior_file(name), "prior")
        assert isinstance(prior, ConditionalRealNVP)
        if (prior.config.latent_dim, prior.config.cond_dim) != (vae.config.latent_dim, vae.config.obs_dim):
            raise SkillModelError(
                f"skill model file {folder / prior_file(name)}: field 'config' has latent_dim "
                f"{prior.config.latent_dim} / cond_dim {prior.config.cond_dim}, the VAE has "
                f"{vae.config.latent_dim} / {vae.config.obs_dim}"
            )
        loaded[name] = prior
        info[name] = prior_info
    return SkillModels(vae, loaded, info)
