"""``seal fit skills``: SEAL's skill models (thesis 6.3.2) from a dataset split.

1. Demonstrations (`seal.experiments.fitting.skill_data`): per source one file, built in parallel and resumably,
   reused when it exists with the same settings: the logged traffic's own drivers (``log``: clean driving, the
   benign windows), the noisy heuristic drivers (``heuristic``) and, with ``ego_rollouts.egos``, an adversary
   in closed loop against egos (heuristic and `seal train` checkpoints).
2. Windows (`seal.models.skills.demos.WindowSpec`): H-step windows; adversarial = starting within 2H before a
   collision or near miss (box gap < 0.5 m while closing) that the agent struck (`seal.models.skills.events`: the
   vehicle whose own motion closes the gap, not the one hit from behind); benign = the other windows of the ``log``
   source; the rest unused; a share of the scenarios is held out for validation and the reported metrics.
3. The skill VAE on benign (capped at ``max_benign_windows``) and adversarial training windows.
4. Two state-conditioned RealNVP priors on the VAE's posterior means, each trained on its own windows (by default
   the adversarial one from scratch, ``adversarial_init: scratch``; ``benign`` fine-tunes it from the benign
   prior, early-stopped on the held-out adversarial NLL, epoch 0 included).
5. Metrics on held-out windows (``metrics.json``): reconstruction error, prior NLL per class for both priors
   (the cross terms too, and the separation: how many nats each prior is better on its own class) against an
   unconditional Gaussian reference, the jerk of decoded skill roll-outs is measured separately
   (`seal.experiments.bench.skills`), the skill-space plot (``embedding.png``, thesis Fig. 6.2), and each prior's
   reach (`seal.models.skills.reach`: the hardest braking / strongest throttle its skills offer per state at noise
   bounds 1, 2, 3, beside the logged drivers' acceleration tails).

Outputs in ``--out``: ``vae.pt``, ``prior_benign.pt``, ``prior_adversarial.pt`` (`seal.models.skills.io`),
``demos_<source>.npz`` (unless ``--demos`` puts them elsewhere), ``config.yaml`` (resolved), ``metrics.json``,
``embedding.png`` and per-model CSV logs. Each model stage is skipped when its file exists and was trained from
the same data and settings (its recorded fingerprint), so an interrupted run resumes after its last finished
stage; within a model's training, ``<model file>.state`` keeps the loop's state after every epoch, and a run
interrupted part way goes on after its last finished epoch with the same result (`seal.models.skills.train.fit_loop`;
the file is removed once the model is saved).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.chunked import fingerprint
from seal.core.config import load_config, overrides_field, to_dict
from seal.experiments import presets
from seal.experiments.fitting.skill_data import EgoRolloutConfig, Rows, cap, get_demonstrations, window_rows
from seal.models.skills.demonstrations import DEMO_SOURCES, DemoConfig
from seal.models.skills.demos import Demonstrations, WindowSpec
from seal.models.skills.realnvp import RealNVPConfig
from seal.models.skills.train import SkillTrainConfig
from seal.models.skills.vae import VAEConfig

logger = logging.getLogger(__name__)

PRESETS = presets.SKILLS_PRESETS
STATE_SUFFIX = ".state"
"""Suffix of a model file's per-epoch training state, kept until the model is saved."""


@dataclass(frozen=True)
class SkillsFitConfig:
    """Settings of ``seal fit skills`` (presets: ``experiments/configs/skills_<preset>.yaml``)."""

    split: str | None = "train"
    """Split to learn from."""
    limit: int | None = None
    """Use the first N scenarios of the split (None: all)."""
    seed: int = 0
    """Random seed (demonstrations, window draws, model initialisation and shuffling)."""
    threads: int = 1
    """Torch threads (set by the command-line entry point)."""
    workers: int = 2
    """Processes building the demonstrations."""
    chunk_size: int = 10
    """Scenarios per resumable demonstration chunk."""
    sources: tuple[str, ...] = ("log", "heuristic")
    """Simulated demonstration sources (`seal.models.skills.demonstrations.DEMO_SOURCES`): ``log`` (the logged
    traffic's own drivers: the benign windows) and ``heuristic`` (noisy drivers: adversarial windows only)."""
    demos: dict[str, Any] = overrides_field(DemoConfig)
    """`seal.models.skills.demonstrations.DemoConfig` overrides (the seed defaults to ``seed``; ``source`` is set
    per entry of ``sources``)."""
    ego_rollouts: dict[str, Any] = overrides_field(EgoRolloutConfig)
    """`seal.experiments.fitting.skill_data.EgoRolloutConfig` overrides: closed-loop roll-outs against egos."""
    windows: dict[str, Any] = overrides_field(WindowSpec)
    """`seal.models.skills.demos.WindowSpec` overrides."""
    val_fraction: float = 0.1
    """Held-out share of the scenarios, in (0, 1)."""
    max_benign_windows: int = 150000
    """Benign training windows kept (drawn at random)."""
    max_val_windows: int = 20000
    """Validation (and metrics) windows kept per class."""
    vae: dict[str, Any] = overrides_field(VAEConfig)
    """`VAEConfig` overrides (obs_dim and horizon default to the data's)."""
    vae_train: dict[str, Any] = overrides_field(
        SkillTrainConfig, batch_size=512, lr=1e-3, max_epochs=20, patience=3, max_minutes=6.0)
    """`SkillTrainConfig` of the VAE (the seed defaults to ``seed``)."""
    prior: dict[str, Any] = overrides_field(RealNVPConfig)
    """`RealNVPConfig` overrides (latent_dim and cond_dim default to the VAE's)."""
    prior_train: dict[str, Any] = overrides_field(
        SkillTrainConfig, batch_size=512, lr=1e-3, max_epochs=60, patience=6, max_minutes=1.5)
    """`SkillTrainConfig` of both priors (the seed defaults to ``seed``)."""
    adversarial_init: Literal["benign", "scratch"] = "scratch"
    """``scratch``: the adversarial prior is trained on its own data only; ``benign``: fine-tuned from the benign
    prior (early-stopped; epoch 0 allowed, so it can stay the benign prior)."""
    plot_states: int = 300
    """Held-out states of the embedding plot."""
    plot_samples_per_state: int = 10
    """Prior samples per state in the embedding plot."""

    def __post_init__(self) -> None:
        """Build every sub-config once, so a bad value fails here and names its section."""
        DemoConfig.from_dict(self.demos, "config key 'demos'")
        EgoRolloutConfig.from_dict(self.ego_rollouts)
        bad = [s for s in self.sources if s not in DEMO_SOURCES]
        if bad:
            raise ValueError(f"config key 'sources': unknown source(s) {bad}; choose from {DEMO_SOURCES}")
        WindowSpec(**self.windows)
        VAEConfig.from_dict(self.vae, "config key 'vae'")
        RealNVPConfig.from_dict(self.prior, "config key 'prior'")
        SkillTrainConfig.from_dict(self.vae_train, "config key 'vae_train'")
        SkillTrainConfig.from_dict(self.prior_train, "config key 'prior_train'")
        if not 0.0 < float(self.val_fraction) < 1.0:
            raise ValueError(f"val_fraction must be in (0, 1), got {self.val_fraction}")
        for key in ("workers", "chunk_size", "max_benign_windows", "max_val_windows", "plot_states",
                    "plot_samples_per_state", "threads"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"{key} must be >= 1, got {getattr(self, key)}")


def preset_file(name: str) -> Path:
    """The YAML preset ``experiments/configs/skills_<name>.yaml``."""
    return presets.preset_file("skills", name, PRESETS)


def resolve_config(preset: str | None = "standard", config_file: str | Path | None = None, sets: Sequence[str] = (),
                   **values: Any) -> SkillsFitConfig:
    """Defaults < preset < YAML config file < ``values`` (None values ignored) < ``sets`` (``key=value``); the
    sub-configs are checked by building each once."""
    return load_config(SkillsFitConfig, preset=None if preset is None else preset_file(preset), file=config_file,
                       values=values, overrides=sets)


def _fit_vae(demos: Demonstrations, rows: Rows, counts: dict[str, int], vae_cfg: VAEConfig, data_fp: str,
             config: SkillsFitConfig, out: Path, progress: bool) -> tuple[Any, str, bool]:
    """The skill VAE (reused from ``out`` when trained from the same data and settings); its fingerprint; reused?"""
    import torch

    from seal.models.skills.io import VAE_FILE, load_model, save_model
    from seal.models.skills.train import train_vae
    from seal.models.skills.vae import SkillVAE

    seed = config.seed
    vae_train = SkillTrainConfig.from_dict({"seed": seed, **config.vae_train})
    vae_fp = fingerprint((data_fp, vae_cfg.to_dict(), vae_train.to_dict()))
    vae = _reuse(out / VAE_FILE, vae_fp, load_model)
    if vae is not None:
        return vae, vae_fp, True
    torch.manual_seed(seed)
    vae = SkillVAE(vae_cfg)
    train_rows = np.concatenate([rows["train", "benign"], rows["train", "adversarial"]])
    val_rows = np.concatenate([rows["val", "benign"], rows["val", "adversarial"]])
    state = out / f"{VAE_FILE}{STATE_SUFFIX}"
    fit = train_vae(vae, demos.obs, demos.actions, train_rows, val_rows, vae_train, out / "vae_log.csv", progress,
                    state, vae_fp)
    save_model(vae, out / VAE_FILE, {"fingerprint": vae_fp, "fit": _fit_info(fit), "windows": counts})
    state.unlink(missing_ok=True)
    logger.info(f"vae: {fit.stop_reason}; best epoch {fit.best_epoch} (val loss {fit.best_val:.4f})")
    return vae, vae_fp, False


def _fit_priors(z: Rows, cond: Rows, counts: dict[str, int], prior_cfg: RealNVPConfig, vae_fp: str,
                config: SkillsFitConfig, out: Path, progress: bool) -> tuple[dict[str, Any], list[str]]:
    """The benign and adversarial priors on posterior means ``z`` conditioned on ``cond`` (reused when trained from
    the same data and settings); the names of the reused ones."""
    import torch

    from seal.models.skills.io import load_model, prior_file, save_model
    from seal.models.skills.realnvp import ConditionalRealNVP
    from seal.models.skills.train import train_prior

    seed = config.seed
    prior_train = SkillTrainConfig.from_dict({"seed": seed, **config.prior_train})
    priors: dict[str, ConditionalRealNVP] = {}
    prior_fps: dict[str, str] = {}
    reused: list[str] = []
    for name in ("benign", "adversarial"):
        from_benign = name == "adversarial" and config.adversarial_init == "benign"
        fp = fingerprint((vae_fp, name, prior_cfg.to_dict(), prior_train.to_dict(),
                          prior_fps["benign"] if from_benign else None))
        prior_fps[name] = fp
        prior = _reuse(out / prior_file(name), fp, load_model)
        if prior is not None:
            reused.append(f"prior_{name}")
        else:
            torch.manual_seed(seed)
            prior = ConditionalRealNVP(prior_cfg)
            if from_benign:
                prior.load_state_dict(priors["benign"].state_dict())
            state = out / f"{prior_file(name)}{STATE_SUFFIX}"
            fit = train_prior(prior, z["train", name], cond["train", name], z["val", name], cond["val", name],
                              prior_train, out / f"prior_{name}_log.csv", progress, f"prior {name}",
                              fit_norm=not from_benign, state_path=state, state_key=fp)
            save_model(prior, out / prior_file(name), {"fingerprint": fp, "fit": _fit_info(fit), "windows": counts})
            state.unlink(missing_ok=True)
            logger.info(f"prior {name}: {fit.stop_reason}; best epoch {fit.best_epoch} (val NLL {fit.best_val:.3f})")
        priors[name] = prior
    return priors, reused


def _held_out_metrics(vae: Any, priors: dict[str, Any], demos: Demonstrations, rows: Rows, z: Rows, cond: Rows,
                      config: SkillsFitConfig, out: Path) -> dict[str, Any]:
    """Reconstruction, prior NLL per class (cross terms too) against a Gaussian reference, and the embedding plot."""
    from seal.experiments.fitting.skill_embedding import plot_embedding, prior_samples
    from seal.models.skills.metrics import gaussian_nll, prior_nll, vae_metrics
    from seal.models.skills.reach import skill_reach

    seed, obs, actions = config.seed, demos.obs, demos.actions
    val_all = np.concatenate([rows["val", "benign"], rows["val", "adversarial"]])
    recon = {
        "all": vae_metrics(vae, obs, actions, val_all, seed),
        "benign": vae_metrics(vae, obs, actions, rows["val", "benign"], seed),
        "adversarial": vae_metrics(vae, obs, actions, rows["val", "adversarial"], seed),
    }
    nll: dict[str, dict[str, Any]] = {}
    for pname, prior in priors.items():
        nll[f"{pname}_prior"] = {
            f"{c}_windows": {k: round(v, 4) for k, v in prior_nll(prior, z["val", c], cond["val", c]).items()}
            for c in ("benign", "adversarial")
        }
    nll["gaussian_reference"] = {
        f"{cname}_windows": {"mean": round(gaussian_nll(z["train", cname], z["val", cname]), 4)}
        for cname in ("benign", "adversarial")
    }
    # The picture: both priors over the same held-out states (drawn from both classes).
    state_rows = cap(val_all, config.plot_states, np.random.default_rng(seed + 1))
    states = obs[state_rows].astype(np.float32)
    samples = {name: prior_samples(p, states, config.plot_samples_per_state, seed + k)
               for k, (name, p) in enumerate(priors.items())}
    embedding = plot_embedding(samples, out / "embedding.png",
                               f"skill latents of both priors over {state_rows.size} held-out states (PCA)")
    # What each prior's skills can do in those states (the hardest braking / throttle a ReSkill ego can pick).
    reach = {name: skill_reach(vae, p, states, actions[state_rows, 1], seed=seed) for name, p in priors.items()}
    return {
        "reconstruction": {k: {m: round(v, 5) if isinstance(v, float) else v for m, v in r.items()}
                           for k, r in recon.items()},
        "action_std_train": [round(float(v), 5) for v in vae.act_std.tolist()],
        "prior_nll_nats": nll,
        # How much better each prior is on its own class (positive = better), by the mean and by the median NLL
        # (a flow's NLL of latents far outside its training data can be huge, so a few windows can carry the mean).
        "prior_separation_nats": {
            f"{c}_windows{suffix}": round(nll[f"{other}_prior"][f"{c}_windows"][stat]
                                          - nll[f"{c}_prior"][f"{c}_windows"][stat], 4)
            for c, other in (("adversarial", "benign"), ("benign", "adversarial"))
            for stat, suffix in (("mean", ""), ("median", "_median"))
        },
        "embedding": embedding,
        "reach": reach,
    }


def fit_skills(dataset: str | Path, out: str | Path, config: SkillsFitConfig, demos_path: str | Path | None = None,
               progress: bool = True) -> dict[str, Any]:
    """Run the pipeline of the module docstring; returns the metrics (also written to ``out/metrics.json``).

    The caller sets torch's threads (the CLI: ``config.threads``)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    demos_dir = Path(demos_path) if demos_path is not None else out
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(
        {**to_dict(config), "dataset": str(dataset), "out": str(out), "demos_path": str(demos_dir)},
        sort_keys=True).encode())
    timings: dict[str, float] = {}
    reused: list[str] = []

    t = time.perf_counter()
    demos, demos_reused = get_demonstrations(dataset, config, demos_dir, progress, own=out)
    timings["demonstrations_s"] = round(time.perf_counter() - t, 1)
    reused += demos_reused
    spec = WindowSpec(**config.windows)
    vae_cfg = VAEConfig.from_dict({"obs_dim": demos.obs_dim, "horizon": spec.horizon, **config.vae})
    if vae_cfg.horizon != spec.horizon:
        raise ValueError(f"config: vae.horizon ({vae_cfg.horizon}) must equal windows.horizon ({spec.horizon})")
    stats = demos.stats(spec)
    logger.info("demonstrations: " + ", ".join(f"{k} {v}" for k, v in stats.items() if not isinstance(v, dict))
                + f", end reasons {stats['end_reasons']}")
    rows, counts = window_rows(demos, spec, config)
    data_fp = fingerprint((demos.params, list(demos.scenario_ids), spec.to_dict(), config.val_fraction,
                           config.max_benign_windows, config.seed))

    t = time.perf_counter()
    vae, vae_fp, vae_reused = _fit_vae(demos, rows, counts, vae_cfg, data_fp, config, out, progress)
    reused += ["vae"] if vae_reused else []
    timings["vae_s"] = round(time.perf_counter() - t, 1)

    # The priors on posterior means, conditioned on each window's first observation.
    from seal.models.skills.train import encode_windows

    t = time.perf_counter()
    z = {key: encode_windows(vae, demos.obs, demos.actions, r) for key, r in rows.items()}
    cond = {key: demos.obs[r].astype(np.float32) for key, r in rows.items()}
    prior_cfg = RealNVPConfig.from_dict({"latent_dim": vae_cfg.latent_dim, "cond_dim": demos.obs_dim,
                                         **config.prior})
    priors, priors_reused = _fit_priors(z, cond, counts, prior_cfg, vae_fp, config, out, progress)
    reused += priors_reused
    timings["priors_s"] = round(time.perf_counter() - t, 1)

    t = time.perf_counter()
    held_out = _held_out_metrics(vae, priors, demos, rows, z, cond, config, out)
    from seal.models.skills.braking_probe import braking_report

    held_out["braking_probe"] = braking_report(vae, priors)  # closed loop: does a skill brake for a braking car?
    timings["metrics_s"] = round(time.perf_counter() - t, 1)
    metrics = {
        "dataset": str(dataset), "split": config.split, "out": str(out), "demos_path": str(demos_dir),
        "demonstrations": stats, "windows_used": counts, "window_spec": spec.to_dict(),
        **held_out,
        "models": {"vae": vae_cfg.to_dict(), "prior": prior_cfg.to_dict()},
        "timings": timings,
        "stages_reused": reused,  # their timings are load times, not training times
    }
    atomic_write_json(out / "metrics.json", metrics)
    return metrics


def _fit_info(fit: Any) -> dict[str, Any]:
    return {"best_epoch": fit.best_epoch, "best_val": fit.best_val, "stop_reason": fit.stop_reason,
            "seconds": fit.seconds, "epochs": len(fit.history)}


def _reuse(path: Path, fingerprint: str, load: Callable[..., Any]) -> Any:
    """The model at ``path`` when it was trained with ``fingerprint`` (resume), else None."""
    if not path.exists():
        return None
    model, info = load(path)
    if info.get("fingerprint") == fingerprint:
        logger.info(f"reusing {path} (same data and settings)")
        return model
    return None


def format_summary(m: dict[str, Any]) -> str:
    """Plain-text report of `fit_skills`' metrics."""
    d, r, nll = m["demonstrations"], m["reconstruction"], m["prior_nll_nats"]
    lines = [
        f"skills written to {m['out']} (demonstrations: {m['demos_path']})",
        f"demonstrations: {d['scenarios']} scenarios, {d['agents']} segments, {d['agent_steps']} agent-steps; "
        f"segments per source {d['agents_per_source']}; end reasons {d['end_reasons']}; events {d['events']}",
        f"windows: benign {d['windows_benign']}, adversarial {d['windows_adversarial']} (per source "
        f"{d['windows_adversarial_per_source']}), dropped {d['windows_dropped']}, unused {d['windows_unused']}; "
        f"used {m['windows_used']}",
        "held-out reconstruction (std-units MSE | shuffled-z MSE | RMSE steering, accel):",
    ]
    for k, v in r.items():
        lines.append(f"  {k:>11}: {v['recon_mse_std']:.4f} | {v['recon_mse_std_shuffled_z']:.4f} | "
                     f"{v['rmse_steering']:.4f}, {v['rmse_accel']:.4f}  ({v['windows']} windows)")
    lines.append("held-out prior NLL, nats / window, mean (median); rows: model, columns: windows benign | adversarial")
    for k, v in nll.items():
        cells = [f"{c['mean']:.3f}" + (f" ({c['median']:.3f})" if "median" in c else "")
                 for c in (v["benign_windows"], v["adversarial_windows"])]
        lines.append(f"  {k:>18}: {cells[0]} | {cells[1]}")
    sep = m["prior_separation_nats"]
    lines.append(f"separation (mean, median NLL): on adversarial windows the adversarial prior is "
                 f"{sep['adversarial_windows']:+.3f}, {sep['adversarial_windows_median']:+.3f} nats better than the "
                 f"benign prior; on benign windows the benign prior is {sep['benign_windows']:+.3f}, "
                 f"{sep['benign_windows_median']:+.3f} nats better than the adversarial prior")
    from seal.models.skills.reach import format_reach

    for name, reach in (m.get("reach") or {}).items():  # absent in reports written before it existed
        lines.append(format_reach(name, reach))
    if "braking_probe" in m:
        from seal.models.skills.braking_probe import format_braking

        lines.append(format_braking(m["braking_probe"]))
    e = m["embedding"]
    lines.append(f"embedding: PCA variance {e['explained_variance']}, prior mean distance "
                 f"{e.get('mean_distance_pooled_std')} pooled std; timings {m['timings']}")
    return "\n".join(lines)
