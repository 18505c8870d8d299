"""``seal fit skills``: SEAL's skill models (thesis 6.3.2) from a dataset split.

1. Demonstrations (`seal.models.skills.demonstrations`): every vehicle of every scenario driven by the noisy heuristic,
   (own observation, action) recorded per step; built in parallel and resumable, reused when the file exists
   with the same settings.
2. Windows (`seal.models.skills.demos.label_windows`): 10-step windows, adversarial = ending within the last 20 steps
   before that agent's collision, dropped = ending within 20 steps of an out-of-road end, the rest benign; a
   share of the scenarios is held out for validation and the reported metrics.
3. The skill VAE on benign (capped at ``max_benign_windows``) and adversarial training windows.
4. Two state-conditioned RealNVP priors on the VAE's posterior means: benign and adversarial windows. By default
   (``adversarial_init: benign``) the adversarial prior starts from the trained benign prior and is fine-tuned on
   the adversarial windows, early-stopped on their held-out NLL (epoch 0 included, so it is never worse than the
   benign prior there): the adversarial windows are ~40x fewer, and from scratch their prior overfits (held-out
   NLL ~1.5 nats worse than the benign prior's on the same windows in our runs). ``scratch`` trains it alone.
5. Metrics on held-out windows (``metrics.json``): reconstruction error, prior NLL per class for both priors
   (the cross terms too) against an unconditional Gaussian reference, and the skill-space plot
   (``embedding.png``, thesis Fig. 6.2).

Outputs in ``--out``: ``vae.pt``, ``prior_benign.pt``, ``prior_adversarial.pt`` (`seal.models.skills.io`),
``demos.npz`` (unless ``--demos`` puts it elsewhere), ``config.yaml`` (resolved), ``metrics.json``,
``embedding.png`` and per-model CSV logs. Each model stage is skipped when its file exists and was trained from
the same data and settings (its recorded fingerprint), so an interrupted run resumes after its last finished
stage.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.experiments import presets
from seal.models.skills.demos import ADVERSARIAL, BENIGN, Demonstrations, WindowSpec, label_windows, split_by_scenario

PRESETS = ("quick", "standard")

DEFAULTS: dict[str, Any] = {
    "split": "train",
    "limit": None,
    "seed": 0,
    "threads": 1,
    "workers": 2,
    "chunk_size": 10,
    "demos": {},
    "windows": {},
    "val_fraction": 0.1,
    "max_benign_windows": 150000,
    "max_val_windows": 20000,
    "vae": {},
    "vae_train": {"batch_size": 512, "lr": 1e-3, "max_epochs": 20, "patience": 3, "max_minutes": 6.0},
    "prior": {},
    "prior_train": {"batch_size": 512, "lr": 1e-3, "max_epochs": 60, "patience": 6, "max_minutes": 1.5},
    "adversarial_init": "benign",
    "plot_states": 300,
    "plot_samples_per_state": 10,
}
"""Config keys: data (``split``, ``limit`` first N scenarios), ``seed``, torch ``threads``, demonstration build
(``workers`` processes, ``chunk_size`` scenarios per resumable chunk, ``demos``:
`seal.models.skills.demonstrations.DemoConfig`
overrides), ``windows`` (`seal.models.skills.demos.WindowSpec` overrides), ``val_fraction`` (held-out share of the
scenarios), ``max_benign_windows`` (benign training windows kept, drawn at random), ``max_val_windows`` (per class,
for validation and metrics), ``vae`` / ``prior`` (`VAEConfig` / `RealNVPConfig` overrides), ``vae_train`` /
``prior_train`` (`seal.models.skills.train.TrainConfig`), ``adversarial_init`` (``benign``: fine-tune the adversarial
prior
from the benign one; ``scratch``), ``plot_states`` and ``plot_samples_per_state`` (the embedding
plot)."""


def load_preset(name: str) -> dict[str, Any]:
    """The YAML preset ``experiments/configs/skills_<name>.yaml``."""
    return presets.load_preset("skills", name, PRESETS, DEFAULTS)


def resolve_config(preset: str | None = "standard", config_file: str | Path | None = None,
                   **overrides: Any) -> dict[str, Any]:
    """Defaults < preset < YAML config file < explicit overrides (None values ignored); validated by building
    every sub-config once."""
    from seal.models.skills.demonstrations import DemoConfig
    from seal.models.skills.realnvp import RealNVPConfig
    from seal.models.skills.train import TrainConfig
    from seal.models.skills.vae import VAEConfig

    config = presets.layered_options("skills", PRESETS, DEFAULTS, preset, config_file, overrides)
    DemoConfig.from_dict(config["demos"], "config key 'demos'")
    WindowSpec(**config["windows"])
    VAEConfig.from_dict(config["vae"], "config key 'vae'")
    RealNVPConfig.from_dict(config["prior"], "config key 'prior'")
    TrainConfig.from_dict(config["vae_train"], "config key 'vae_train'")
    TrainConfig.from_dict(config["prior_train"], "config key 'prior_train'")
    if config["adversarial_init"] not in ("benign", "scratch"):
        raise ValueError(f"adversarial_init must be 'benign' or 'scratch', got {config['adversarial_init']!r}")
    if not 0.0 < float(config["val_fraction"]) < 1.0:
        raise ValueError(f"val_fraction must be in (0, 1), got {config['val_fraction']}")
    for key in ("workers", "chunk_size", "max_benign_windows", "max_val_windows", "plot_states",
                "plot_samples_per_state", "threads"):
        if int(config[key]) < 1:
            raise ValueError(f"{key} must be >= 1, got {config[key]}")
    return config


def _fingerprint(*parts: Any) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def get_demonstrations(
    dataset: str | Path, config: dict[str, Any], path: Path, progress: bool, log: Callable[[str], None]
) -> tuple[Demonstrations, bool]:
    """The demonstrations of the configured split and whether they were reused from ``path`` (same scenarios and
    settings) rather than built (resumably) and written there."""
    from seal.core.dataset import Dataset
    from seal.models.skills.demonstrations import DemoConfig, build_demonstrations

    ds = Dataset.open(dataset)
    split = config["split"]
    if split is not None and split not in ds.splits:
        raise ValueError(f"dataset {dataset} has no split {split!r}; splits: {sorted(ds.splits) or 'none'}")
    scenarios = ds.load(split=split, limit=config["limit"])
    if len(scenarios) < 2:
        raise ValueError(f"dataset {dataset}: split {split!r} has {len(scenarios)} scenario(s); need at least 2")
    demo_cfg = DemoConfig.from_dict({"seed": config["seed"], **config["demos"]}, "config key 'demos'")
    ids = [s.scenario_id for s in scenarios]
    if path.exists():
        demos = Demonstrations.load(path)
        if demos.params == demo_cfg.to_dict() and list(demos.scenario_ids) == ids:
            log(f"demonstrations: reusing {path} ({demos.n_segments} agents, {demos.n_rows} steps)")
            return demos, True
        log(f"demonstrations: {path} was built from other scenarios or settings; rebuilding")
    log(f"demonstrations: simulating {len(scenarios)} scenarios of split {split!r} with {config['workers']} processes")
    demos = build_demonstrations(scenarios, path, demo_cfg, workers=int(config["workers"]),
                                 chunk_size=int(config["chunk_size"]), progress=progress)
    return demos, False


def _cap(rows: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return rows if rows.size <= n else np.sort(rng.choice(rows, n, replace=False))


def fit_skills(
    dataset: str | Path, out: str | Path, config: dict[str, Any], demos_path: str | Path | None = None,
    progress: bool = True, log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run the pipeline of the module docstring; returns the metrics (also written to ``out/metrics.json``)."""
    import torch

    from seal.experiments.fitting.skill_embedding import plot_embedding, prior_samples
    from seal.models.skills.io import VAE_FILE, load_model, prior_file, save_model
    from seal.models.skills.metrics import gaussian_nll, prior_nll, vae_metrics
    from seal.models.skills.realnvp import ConditionalRealNVP, RealNVPConfig
    from seal.models.skills.train import TrainConfig, encode_windows, train_prior, train_vae
    from seal.models.skills.vae import SkillVAE, VAEConfig

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    demos_file = Path(demos_path) if demos_path is not None else out / "demos.npz"
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(
        {**config, "dataset": str(dataset), "out": str(out), "demos_path": str(demos_file)}, sort_keys=True).encode())
    torch.set_num_threads(int(config["threads"]))
    timings: dict[str, float] = {}
    reused: list[str] = []

    t = time.perf_counter()
    demos, demos_reused = get_demonstrations(dataset, config, demos_file, progress, log)
    timings["demonstrations_s"] = round(time.perf_counter() - t, 1)
    if demos_reused:
        reused.append("demonstrations")
    spec = WindowSpec(**config["windows"])
    vae_cfg = VAEConfig.from_dict({"obs_dim": demos.obs_dim, "horizon": spec.horizon, **config["vae"]})
    if vae_cfg.horizon != spec.horizon:
        raise ValueError(f"config: vae.horizon ({vae_cfg.horizon}) must equal windows.horizon ({spec.horizon})")
    stats = demos.stats(spec)
    log("demonstrations: " + ", ".join(f"{k} {v}" for k, v in stats.items() if not isinstance(v, dict))
        + f", end reasons {stats['end_reasons']}")

    # Windows, held out by scenario; per class capped for training (benign) and validation (both).
    seed = int(config["seed"])
    rng = np.random.default_rng(seed)
    windows = label_windows(demos.seg_row, demos.seg_len, demos.seg_end_reason, spec)
    train_w, val_w = split_by_scenario(windows, demos.seg_scenario, len(demos.scenario_ids),
                                       float(config["val_fraction"]), seed)
    rows = {
        ("train", name): train_w.row[train_w.label == label] for label, name in ((BENIGN, "benign"),
                                                                                 (ADVERSARIAL, "adversarial"))
    }
    rows.update({("val", name): val_w.row[val_w.label == label] for label, name in ((BENIGN, "benign"),
                                                                                  (ADVERSARIAL, "adversarial"))})
    rows["train", "benign"] = _cap(rows["train", "benign"], int(config["max_benign_windows"]), rng)
    for name in ("benign", "adversarial"):
        rows["val", name] = _cap(rows["val", name], int(config["max_val_windows"]), rng)
    counts = {f"{split}_{name}": int(r.size) for (split, name), r in rows.items()}
    log("windows used: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    for key, n in counts.items():
        if n == 0:
            raise ValueError(f"no {key.replace('_', ' ')} windows: simulate more scenarios (--limit) or raise the "
                             "demonstration noise (config key 'demos')")
    obs, actions = demos.obs, demos.actions
    data_fp = _fingerprint(demos.params, list(demos.scenario_ids), spec.to_dict(), config["val_fraction"],
                           config["max_benign_windows"], seed)

    # The VAE.
    t = time.perf_counter()
    vae_train = TrainConfig.from_dict({"seed": seed, **config["vae_train"]})
    vae_fp = _fingerprint(data_fp, vae_cfg.to_dict(), vae_train.to_dict())
    vae = _reuse(out / VAE_FILE, vae_fp, load_model, log)
    if vae is not None:
        reused.append("vae")
    else:
        torch.manual_seed(seed)
        vae = SkillVAE(vae_cfg)
        train_rows = np.concatenate([rows["train", "benign"], rows["train", "adversarial"]])
        val_rows = np.concatenate([rows["val", "benign"], rows["val", "adversarial"]])
        fit = train_vae(vae, obs, actions, train_rows, val_rows, vae_train, out / "vae_log.csv", progress)
        save_model(vae, out / VAE_FILE, {"fingerprint": vae_fp, "fit": _fit_info(fit), "windows": counts})
        log(f"vae: {fit.stop_reason}; best epoch {fit.best_epoch} (val loss {fit.best_val:.4f})")
    timings["vae_s"] = round(time.perf_counter() - t, 1)

    # The priors on posterior means, conditioned on each window's first observation.
    t = time.perf_counter()
    z = {key: encode_windows(vae, obs, actions, r) for key, r in rows.items()}
    cond = {key: obs[r].astype(np.float32) for key, r in rows.items()}
    prior_cfg = RealNVPConfig.from_dict({"latent_dim": vae_cfg.latent_dim, "cond_dim": demos.obs_dim,
                                         **config["prior"]})
    prior_train = TrainConfig.from_dict({"seed": seed, **config["prior_train"]})
    priors: dict[str, ConditionalRealNVP] = {}
    prior_fps: dict[str, str] = {}
    for name in ("benign", "adversarial"):
        from_benign = name == "adversarial" and config["adversarial_init"] == "benign"
        fp = _fingerprint(vae_fp, name, prior_cfg.to_dict(), prior_train.to_dict(),
                          prior_fps["benign"] if from_benign else None)
        prior_fps[name] = fp
        prior = _reuse(out / prior_file(name), fp, load_model, log)
        if prior is not None:
            reused.append(f"prior_{name}")
        else:
            torch.manual_seed(seed)
            prior = ConditionalRealNVP(prior_cfg)
            if from_benign:
                prior.load_state_dict(priors["benign"].state_dict())
            fit = train_prior(prior, z["train", name], cond["train", name], z["val", name], cond["val", name],
                              prior_train, out / f"prior_{name}_log.csv", progress, f"prior {name}",
                              fit_norm=not from_benign)
            save_model(prior, out / prior_file(name), {"fingerprint": fp, "fit": _fit_info(fit), "windows": counts})
            log(f"prior {name}: {fit.stop_reason}; best epoch {fit.best_epoch} (val NLL {fit.best_val:.3f})")
        priors[name] = prior
    timings["priors_s"] = round(time.perf_counter() - t, 1)

    # Held-out metrics.
    t = time.perf_counter()
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
    n_states = int(config["plot_states"])
    state_rows = _cap(val_all, n_states, np.random.default_rng(seed + 1))
    states = obs[state_rows].astype(np.float32)
    samples = {name: prior_samples(p, states, int(config["plot_samples_per_state"]), seed + k)
               for k, (name, p) in enumerate(priors.items())}
    embedding = plot_embedding(samples, out / "embedding.png",
                               f"skill latents of both priors over {state_rows.size} held-out states (PCA)")
    timings["metrics_s"] = round(time.perf_counter() - t, 1)

    metrics = {
        "dataset": str(dataset), "split": config["split"], "out": str(out), "demos_path": str(demos_file),
        "demonstrations": stats, "windows_used": counts, "window_spec": spec.to_dict(),
        "reconstruction": {k: {m: round(v, 5) if isinstance(v, float) else v for m, v in r.items()}
                           for k, r in recon.items()},
        "action_std_train": [round(float(v), 5) for v in vae.act_std.tolist()],
        "prior_nll_nats": nll,
        "embedding": embedding,
        "models": {"vae": vae_cfg.to_dict(), "prior": prior_cfg.to_dict()},
        "timings": timings,
        "stages_reused": reused,  # their timings are load times, not training times
    }
    atomic_write_json(out / "metrics.json", metrics)
    return metrics


def _fit_info(fit: Any) -> dict[str, Any]:
    return {"best_epoch": fit.best_epoch, "best_val": fit.best_val, "stop_reason": fit.stop_reason,
            "seconds": fit.seconds, "epochs": len(fit.history)}


def _reuse(path: Path, fingerprint: str, load: Callable[..., Any], log: Callable[[str], None]) -> Any:
    """The model at ``path`` when it was trained with ``fingerprint`` (resume), else None."""
    if not path.exists():
        return None
    model, info = load(path)
    if info.get("fingerprint") == fingerprint:
        log(f"reusing {path} (same data and settings)")
        return model
    return None


def format_summary(m: dict[str, Any]) -> str:
    """Plain-text report of `fit_skills`' metrics."""
    d, r, nll = m["demonstrations"], m["reconstruction"], m["prior_nll_nats"]
    lines = [
        f"skills written to {m['out']} (demonstrations: {m['demos_path']})",
        f"demonstrations: {d['scenarios']} scenarios, {d['agents']} agents, {d['agent_steps']} agent-steps; "
        f"end reasons {d['end_reasons']}; collision share {d['collision_share_agents']:.3f} of agents "
        f"({d['collision_share_scenarios']:.2f} of scenarios)",
        f"windows: benign {d['windows_benign']}, adversarial {d['windows_adversarial']}, dropped "
        f"{d['windows_dropped']}; used {m['windows_used']}",
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
    e = m["embedding"]
    lines.append(f"embedding: PCA variance {e['explained_variance']}, prior mean distance "
                 f"{e.get('mean_distance_pooled_std')} pooled std; timings {m['timings']}")
    return "\n".join(lines)
