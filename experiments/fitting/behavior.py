"""``seal fit behavior``: RCG's behaviour embedding (thesis 7.3) and its analysis (Table 7.5).

1. Samples (`seal.experiments.fitting.behavior_data`): everyday behaviours of the training split with SafeShift
   labels (delta chosen for even classes), the same for the held-out split, and the crash set.
2. Per seed, two pre-trainings (``L_recon + lambda L_ProtoNCE`` and ``L_recon`` alone), each then fine-tuned on the
   crash set (LoRA, ``L_ProtoNCE`` alone): four variants, Table 7.5's rows:
   ``no_cl`` (recon only), ``no_cl_ft`` (recon only + fine-tuning; "TADS FT"), ``cl`` ("CL Pre"), ``full``
   ("CL Pre + TADS FT").
3. Each variant's unsafe cache: its embeddings of the training samples labelled unsafe (a seeded draw of at most
   ``cache_max``) and of the crash set's unsafe agents; saved in the model file.
4. Analysis on the held-out samples: per-class k-means sub-clustering silhouette and Davies-Bouldin (averaged over
   N_km = 3..6) and a linear probe of the safety labels fitted on training embeddings; per variant, mean and
   standard deviation over the seeds. The same metrics on the crash set of the held-out split (its collisions and
   near misses, labelled striker / reacting / non-reacting as the fine-tuning data; the probe fitted on the
   training crash set): what fine-tuning trains for, on pairs it has not seen (``crash_table``; None when the
   held-out split has no crash pair).

Outputs in ``--out``: ``behavior.pt`` (the full variant of the first seed: what ``cat-rcg`` / ``seal-rcg`` load),
``variants/<variant>-s<seed>.pt``, ``report.json``, ``report.md``, ``train_log.csv``, ``config.yaml``. Until the
report is written each finished training stage is also kept in ``stages/``: a fit that was interrupted, started
again with the same settings, goes on after its last finished stage and writes the same models
(`seal.experiments.fitting.behavior_stages`; the report lists the stages it loaded, ``resumed_stages``).
"""

from __future__ import annotations

import copy
import csv
import io
import logging
import time
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.config import load_config, overrides_field, to_dict
from seal.experiments import presets
from seal.models.behavior.crash_set import CrashSetConfig
from seal.models.behavior.features import BehaviorFeatureConfig
from seal.models.behavior.network import BehaviorConfig
from seal.models.behavior.train import BehaviorTrainConfig

if typing.TYPE_CHECKING:
    from seal.experiments.fitting.behavior_data import SampleSet
    from seal.experiments.fitting.behavior_stages import StageStore
    from seal.models.behavior.model import BehaviorModel

logger = logging.getLogger(__name__)

PRESETS = ("quick", "standard")
MODEL_FILE = "behavior.pt"
VARIANTS = ("no_cl", "no_cl_ft", "cl", "full")
"""Table 7.5's rows: (contrastive pre-training, fine-tuning) = (no, no), (no, yes), (yes, no), (yes, yes)."""
VARIANT_TITLES = {"no_cl": "No CL", "no_cl_ft": "FT only (no CL)", "cl": "CL Pre", "full": "CL Pre + FT"}


@dataclass(frozen=True)
class BehaviorFitConfig:
    """Settings of ``seal fit behavior`` (presets: ``experiments/configs/behavior_<preset>.yaml``)."""

    split: str = "all-but-eval"
    """Split of the pre-training behaviours and of the crash set (all-but-eval: every scenario outside eval / hard
    and their recordings / traffic runs)."""
    eval_split: str = "eval"
    """Held-out split of the embedding analysis."""
    limit: int | None = None
    """Use the first N training scenarios (None: all)."""
    eval_limit: int | None = None
    """Use the first N held-out scenarios (None: all)."""
    max_samples: int | None = None
    """At most this many pre-training behaviours (a seeded draw; None: all)."""
    min_valid_rows: int = 8
    """Sub-sampled rows an agent must be valid on to be a sample."""
    crash_datasets: tuple[Path, ...] = ()
    """More datasets whose near misses / collisions join the crash set (e.g. imported recordings)."""
    seeds: tuple[int, ...] = (0,)
    """Training seeds (Table 7.5 averages three)."""
    cache_max: int = 4000
    """Most everyday unsafe embeddings in the unsafe cache (the crash set's unsafe agents are always in)."""
    analysis_max: int = 3000
    """Most held-out samples in the clustering metrics (a seeded draw; the pairwise distances are N x N)."""
    probe_max: int = 8000
    """Most training samples the linear probe is fitted on."""
    threads: int = 1
    """Torch threads (set by the command-line entry point)."""
    features: dict[str, Any] = overrides_field(BehaviorFeatureConfig)
    """`seal.models.behavior.BehaviorFeatureConfig` overrides."""
    model: dict[str, Any] = overrides_field(BehaviorConfig)
    """`seal.models.behavior.BehaviorConfig` overrides (without ``features``)."""
    train: dict[str, Any] = overrides_field(BehaviorTrainConfig)
    """`seal.models.behavior.BehaviorTrainConfig` overrides (its seed is set per run from ``seeds``)."""
    crash: dict[str, Any] = overrides_field(CrashSetConfig)
    """`seal.models.behavior.crash_set.CrashSetConfig` overrides."""

    def __post_init__(self) -> None:
        if "features" in self.model:
            raise ValueError("config key 'model.features': set the encoder inputs under 'features' instead")
        self.network()
        self.train_config(0)
        for key in ("limit", "eval_limit", "max_samples"):
            if getattr(self, key) is not None and int(getattr(self, key)) < 1:
                raise ValueError(f"config key {key!r} must be >= 1 or null, got {getattr(self, key)}")
        for key in ("min_valid_rows", "cache_max", "analysis_max", "probe_max", "threads"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"config key {key!r} must be >= 1, got {getattr(self, key)}")
        if not self.seeds:
            raise ValueError("config key 'seeds' must name at least one seed")

    def network(self) -> BehaviorConfig:
        return BehaviorConfig(features=BehaviorFeatureConfig(**self.features), **self.model)

    def train_config(self, seed: int) -> BehaviorTrainConfig:
        return BehaviorTrainConfig(**{**self.train, "seed": seed})

    def crash_config(self) -> CrashSetConfig:
        return CrashSetConfig(**self.crash)

    def to_dict(self) -> dict[str, Any]:
        return typing.cast(dict[str, Any], to_dict(self))


def preset_file(name: str) -> Path:
    """The YAML preset ``experiments/configs/behavior_<name>.yaml``."""
    return presets.preset_file("behavior", name, PRESETS)


def resolve_config(preset: str | None = "standard", config_file: str | Path | None = None, sets: Sequence[str] = (),
                   **values: Any) -> BehaviorFitConfig:
    """Defaults < preset < YAML config file < ``values`` (None values ignored) < ``sets`` (``key=value``)."""
    return load_config(BehaviorFitConfig, preset=None if preset is None else preset_file(preset), file=config_file,
                       values=values, overrides=sets)


@dataclass
class Data:
    """Everything the variants train and are judged on."""

    train: SampleSet
    held_out: SampleSet
    crash: SampleSet
    delta: float
    crash_summary: dict[str, Any]
    held_out_crash: SampleSet | None = None
    """The held-out split's crash set (None: no pair there collides or comes close)."""


def load_data(dataset: str | Path, config: BehaviorFitConfig) -> Data:
    from seal.experiments.fitting.behavior_data import crash_set, everyday_samples, label_everyday

    feats = config.network().features
    train, scenarios = everyday_samples(dataset, config.split, config.limit, feats, config.min_valid_rows,
                                        config.max_samples, config.seeds[0])
    held_out, held_scenarios = everyday_samples(dataset, config.eval_split, config.eval_limit, feats,
                                                config.min_valid_rows, None, config.seeds[0])
    delta = label_everyday(train, held_out)
    crash, summary = crash_set(scenarios, config.crash_datasets, feats, config.crash_config())
    try:
        held_crash, _ = crash_set(held_scenarios, (), feats, config.crash_config())
    except ValueError:  # no crash pair in the held-out split: that analysis is left out
        held_crash = None
    return Data(train, held_out, crash, delta, summary, held_crash)


def _unsafe_cache(model: BehaviorModel, data: Data, cache_max: int, seed: int) -> dict[str, int]:
    from seal.models.behavior.labels import UNSAFE

    rows = np.flatnonzero(data.train.labels == UNSAFE)
    if rows.size > cache_max:
        rows = np.sort(np.random.default_rng(seed).choice(rows, cache_max, replace=False))
    crash_rows = np.flatnonzero(data.crash.labels == UNSAFE)
    parts = [model.embed(data.train.inputs.take(rows)), model.embed(data.crash.inputs.take(crash_rows))]
    model.set_unsafe_cache(np.concatenate(parts))
    return {"everyday_unsafe": int(rows.size), "crash_unsafe": int(crash_rows.size)}


def fit_variants(data: Data, config: BehaviorFitConfig, seed: int, bar: Any = None, stages: StageStore | None = None
                 ) -> tuple[dict[str, BehaviorModel], list[dict]]:
    """The four variants of one seed (see the module docstring) and their training log rows; ``bar`` (a tqdm
    bar) advances once per training stage; ``stages``: where finished stages are kept and loaded from (None:
    train every stage, keep none)."""
    import torch

    from seal.models.behavior.model import BehaviorModel
    from seal.models.behavior.network import BehaviorNet
    from seal.models.behavior.train import Tensors, finetune, pretrain

    net_cfg = config.network()
    scale = net_cfg.features.pos_scale_m
    train_t = Tensors.of(data.train.inputs, data.train.labels, scale)
    crash_t = Tensors.of(data.crash.inputs, data.crash.labels, scale)
    models: dict[str, BehaviorModel] = {}
    log: list[dict] = []
    for contrastive, base, tuned in ((False, "no_cl", "no_cl_ft"), (True, "cl", "full")):
        tcfg = BehaviorTrainConfig(**{**config.train_config(seed).to_dict(), "contrastive": contrastive})
        stored = None if stages is None else stages.load(base, seed)
        if stored is None:
            torch.manual_seed(seed)
            net = BehaviorNet(net_cfg)
            start = time.monotonic()
            protos, rows = pretrain(net, train_t, tcfg)
            info = {"variant": base, "seed": seed, "train_seconds": round(time.monotonic() - start, 1)}
            models[base] = BehaviorModel(net_cfg, net, protos, lora=False, info=info)
            if stages is not None:
                stages.save(base, seed, models[base], rows)
        else:
            models[base], rows = stored
        if bar is not None:
            bar.update()
        log += [{"variant": base, "seed": seed, **r} for r in rows]
        stored = None if stages is None else stages.load(tuned, seed)
        if stored is None:
            base_protos = models[base].prototypes
            if base_protos is None:  # only a stage file written by something else can lack them
                raise ValueError(f"fit behavior: the pre-trained stage {base}-s{seed} has no prototypes; delete "
                                 "the stages folder of --out to train it again")
            tuned_net = copy.deepcopy(models[base].net)
            start = time.monotonic()
            tuned_protos, rows = finetune(tuned_net, crash_t, tcfg, base_protos)
            models[tuned] = BehaviorModel(net_cfg, tuned_net, tuned_protos, lora=True,
                                          info={"variant": tuned, "seed": seed,
                                                "finetune_seconds": round(time.monotonic() - start, 1)})
            if stages is not None:
                stages.save(tuned, seed, models[tuned], rows)
        else:
            models[tuned], rows = stored
        if bar is not None:
            bar.update()
        log += [{"variant": tuned, "seed": seed, **r} for r in rows]
    for m in models.values():
        m.info["unsafe_cache"] = _unsafe_cache(m, data, config.cache_max, seed)
        m.info["delta"] = data.delta
    return models, log


def analyse(model: BehaviorModel, data: Data, config: BehaviorFitConfig, seed: int) -> dict[str, float]:
    """Table 7.5's metrics of one model (see the module docstring)."""
    from seal.models.behavior.analysis import cluster_quality, linear_probe

    rng = np.random.default_rng(seed)
    held = data.held_out
    rows = np.arange(len(held)) if len(held) <= config.analysis_max else np.sort(
        rng.choice(len(held), config.analysis_max, replace=False))
    v_held = model.embed(held.inputs.take(rows))
    quality = cluster_quality(v_held, held.labels[rows], seed=seed)
    train_rows = np.arange(len(data.train)) if len(data.train) <= config.probe_max else np.sort(
        rng.choice(len(data.train), config.probe_max, replace=False))
    v_train = model.embed(data.train.inputs.take(train_rows))
    probe = linear_probe(v_train, data.train.labels[train_rows], model.embed(held.inputs), held.labels, seed=seed)
    return {**quality, "probe_accuracy": probe}


def analyse_crash(model: BehaviorModel, data: Data, seed: int) -> dict[str, float] | None:
    """Table 7.5's metrics on the held-out crash set (its crash roles as classes; the probe fitted on the training
    crash set), and the share of its majority class (a probe's floor); None without a held-out crash set."""
    from seal.models.behavior.analysis import cluster_quality, linear_probe

    held = data.held_out_crash
    if held is None:
        return None
    v_held = model.embed(held.inputs)
    quality = cluster_quality(v_held, held.labels, seed=seed)
    probe = linear_probe(model.embed(data.crash.inputs), data.crash.labels, v_held, held.labels, seed=seed)
    majority = float(np.bincount(held.labels).max() / len(held))
    return {**quality, "probe_accuracy": probe, "majority_share": majority}


def fit_behavior(dataset: str | Path, out: str | Path, config: BehaviorFitConfig, progress: bool = False
                 ) -> dict[str, Any]:
    """Run the whole job (see the module docstring); returns the report. ``progress``: a bar over the training
    stages and analyses (4 stages + 4 analyses per seed)."""
    from tqdm import tqdm

    from seal.experiments.fitting.behavior_stages import StageStore

    out = Path(out)
    (out / "variants").mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(config.to_dict(), sort_keys=False).encode())
    start = time.monotonic()
    data = load_data(dataset, config)
    logger.info("samples: train %d, held-out %d, crash %d (delta %.3f)", len(data.train), len(data.held_out),
                len(data.crash), data.delta)
    stages = StageStore(out, {"config": config.to_dict(), "dataset": str(Path(dataset).resolve()),
                              "samples": [len(data.train), len(data.held_out), len(data.crash)],
                              "delta": data.delta})
    metrics: dict[str, list[dict[str, float]]] = {v: [] for v in VARIANTS}
    crash_metrics: dict[str, list[dict[str, float]]] = {v: [] for v in VARIANTS}
    log: list[dict] = []
    bar = tqdm(total=8 * len(config.seeds), desc="fit behavior", unit="stage", disable=not progress)
    for seed in config.seeds:
        models, rows = fit_variants(data, config, seed, bar, stages)
        log += rows
        for name, model in models.items():
            model.save(out / "variants" / f"{name}-s{seed}.pt")
            metrics[name].append(analyse(model, data, config, seed))
            on_crash = analyse_crash(model, data, seed)
            if on_crash is not None:
                crash_metrics[name].append(on_crash)
            bar.update()
            logger.info("seed %d %s: %s", seed, name, metrics[name][-1])
        if seed == config.seeds[0]:
            models["full"].save(out / MODEL_FILE)
    bar.close()
    table = {v: _mean_std(metrics[v]) for v in VARIANTS}
    report: dict[str, Any] = {
        "dataset": str(dataset), "seeds": list(config.seeds), "delta": data.delta,
        "samples": {"train": data.train.summary(), "held_out": data.held_out.summary(),
                    "crash": data.crash.summary(),
                    "held_out_crash": None if data.held_out_crash is None else data.held_out_crash.summary()},
        "crash_sources": data.crash_summary,
        "table_7_5": table,
        "per_seed": metrics,
        "crash_table": ({v: _mean_std(crash_metrics[v]) for v in VARIANTS}
                        if data.held_out_crash is not None else None),
        "seconds": round(time.monotonic() - start, 1),
        "model": str(out / MODEL_FILE),
    }
    report["full_beats"] = _full_beats(table)
    if report["crash_table"] is not None:
        report["full_beats_on_crash"] = _full_beats(report["crash_table"])
    report["resumed_stages"] = stages.loaded
    atomic_write_json(out / "report.json", report)
    atomic_write_bytes(out / "report.md", format_summary(report).encode())
    _write_log(out / "train_log.csv", log)
    stages.finish()
    return report


def _mean_std(rows: list[dict[str, float]]) -> dict[str, float]:
    keys = rows[0].keys() if rows else ()
    out = {}
    for k in keys:
        vals = np.array([r[k] for r in rows])
        out[k] = round(float(vals.mean()), 4)
        out[f"{k}_std"] = round(float(vals.std()), 4)
    return out


def _full_beats(table: dict[str, dict[str, float]]) -> dict[str, dict[str, bool]]:
    """Per ablation, whether the full variant is better on each metric (higher silhouette / probe, lower DB)."""
    full = table["full"]
    return {v: {"silhouette": full["silhouette"] > table[v]["silhouette"],
                "davies_bouldin": full["davies_bouldin"] < table[v]["davies_bouldin"],
                "probe_accuracy": full["probe_accuracy"] > table[v]["probe_accuracy"]}
            for v in VARIANTS if v != "full"}


def _write_log(path: Path, rows: list[dict]) -> None:
    keys = sorted({k for r in rows for k in r})
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=keys)
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(path, buf.getvalue().encode())


def format_summary(report: dict[str, Any]) -> str:
    """Markdown: sample counts and the Table 7.5 analogue."""
    s = report["samples"]
    lines = [
        f"# Behaviour embedding ({report['dataset']}, seeds {report['seeds']})", "",
        f"delta = {report['delta']:.4f}; samples: train {s['train']}, held-out {s['held_out']}, crash {s['crash']}",
        "", f"crash set sources: {report['crash_sources']}", "",
        "Held-out everyday behaviours, SafeShift safety classes (Table 7.5):", "",
        *_metric_table(report["table_7_5"]),
        "", f"full beats: {report['full_beats']}",
    ]
    if report.get("crash_table") is not None:
        lines += ["", f"Held-out crash set ({s['held_out_crash']}), crash roles as classes (what fine-tuning trains "
                  "for; the probe is fitted on the training crash set):", "",
                  *_metric_table(report["crash_table"]),
                  "", f"full beats on the held-out crash set: {report['full_beats_on_crash']}"]
    lines += [f"seconds: {report['seconds']}", ""]
    return "\n".join(lines)


def _metric_table(table: dict[str, dict[str, float]]) -> list[str]:
    lines = ["| variant | silhouette (up) | Davies-Bouldin (down) | linear probe acc. (up) |", "|---|---|---|---|"]
    for v in VARIANTS:
        r = table[v]
        lines.append(f"| {VARIANT_TITLES[v]} | {r['silhouette']:.3f} +- {r['silhouette_std']:.3f} | "
                     f"{r['davies_bouldin']:.3f} +- {r['davies_bouldin_std']:.3f} | "
                     f"{100 * r['probe_accuracy']:.1f} % +- {100 * r['probe_accuracy_std']:.1f} |")
    return lines
