"""``seal fit objective`` / ``seal eval objective``: SEAL's learned objective pi_score (thesis 6.3.1).

1. Labels (`seal.experiments.fitting.objective_labels`): for every scenario of the training split and of the held-out
split,
   the 32 prior candidates and the logged adversary are rolled out against the heuristic ego (resumable chunks
   under ``OUT/labels/<split>/``, in parallel).
2. Training (`seal.models.objective.train`): MSE on [f_coll, f_diff] over groups of (previous roll-out, all candidates)
   pairs, plus a penalty keeping the logits near closeness (and optionally a listwise ranking loss); early stopping
   and model selection on the validation Spearman of a held-out share of the training scenarios
   (``train_log.csv`` has it per epoch, next to the same metric on training scenarios: over- or under-fitting).
3. Report on the held-out split (scenarios never trained on; `seal.experiments.fitting.objective_eval`),
   ``report.json`` + ``report.md``:

   * MSE per head over all pairs and over the pairs whose previous roll-out is the logged-adversary episode;
   * ranking with the logged-adversary episode as the previous roll-out: Spearman correlation between the score
     and the simulated ``f_coll + f_diff`` over the 32 candidates of a scenario (mean over scenarios), how often
     the score's top-1 is in the simulated top-3, and the simulated value of the chosen candidate;
   * the same for K = 5 previous roll-outs (the logged one and 4 drawn from the candidates' episodes; the
     simulated value is ``f_coll + mean_i f_diff_i``), which is how SEAL uses the score;
   * baselines scored the same way: closeness (``exp(-min_t distance / 8)`` between candidate and previous
     roll-out: f_coll assuming the ego does not react), CAT's heuristic score (ties broken by closeness) and the
     prior probability;
   * ``rank()`` latency for 32 candidates x K = 5 on one thread.

Outputs in ``--out``: ``objective.pt`` (+ ``objective.json``), ``labels/``, ``config.yaml`` (resolved),
``train_log.csv``, ``report.json``, ``report.md``.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import logging
import time
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from seal.core.atomic import atomic_write_bytes
from seal.core.config import load_config, overrides_field, to_dict
from seal.envs.skill_behavior import ADVERSARIAL_STEPS, SKILL_NOISE_SCALE
from seal.experiments import presets
from seal.experiments.fitting.objective_eval import evaluate, label_stats, rank_latency_ms
from seal.experiments.fitting.objective_report import write_report
from seal.models.objective.labels import LabelSet
from seal.models.objective.network import ObjectiveConfig
from seal.models.objective.train import ObjectiveTrainConfig, fit_diagnosis

logger = logging.getLogger(__name__)

PRESETS = ("quick", "standard")
MODEL_FILE = "objective.pt"


@dataclass(frozen=True)
class ObjectiveFitConfig:
    """Settings of ``seal fit objective`` / ``seal eval objective`` (presets:
    ``experiments/configs/objective_<preset>.yaml``)."""

    split: str = "train"
    """Split of the training scenarios."""
    eval_split: str = "eval"
    """Split of the held-out report."""
    limit: int | None = None
    """Use the first N training scenarios (None: all)."""
    eval_limit: int | None = None
    """Use the first N held-out scenarios (None: all)."""
    prior: Path | None = None
    """Trajectory prior file giving the candidates (exactly one of ``prior`` / ``candidates``)."""
    candidates: str | None = None
    """Built-in candidate source name instead of a prior (lanes | constant_velocity)."""
    n_candidates: int = 32
    """Candidates per scenario."""
    seed: int = 0
    """Random seed."""
    threads: int = 1
    """Torch threads of training (set by the command-line entry point)."""
    workers: int = 2
    """Processes simulating the labels."""
    chunk_size: int = 10
    """Scenarios per resumable label chunk."""
    behavior: str = "replay"
    """How the adversary drives each candidate in the label roll-outs: ``replay`` (CAT's way) or ``seal`` (follow
    the candidate, then SEAL's skill switch; needs ``skills``), `seal.experiments.fitting.objective_labels`."""
    skills: Path | None = None
    """Skills folder (`seal fit skills`) of the ``seal`` label behaviour."""
    egos: tuple[str, ...] = ("heuristic",)
    """Egos of the label roll-outs: ``heuristic`` and / or `seal train` run folders; one label row per ego."""
    switch_offset_steps: int = 10
    """``seal`` behaviour: steps between the skill switch and the predicted contact (as the generator)."""
    noise_scale: float = SKILL_NOISE_SCALE
    """``seal`` behaviour: skill noise scale (as the generator, `seal.envs.skill_behavior.SKILL_NOISE_SCALE`)."""
    adversarial_steps: int | None = ADVERSARIAL_STEPS
    """``seal`` behaviour: steps of adversarial skills after the switch before the benign prior's (None: to the end;
    as the generator, `seal.envs.skill_behavior.ADVERSARIAL_STEPS`)."""
    labels_from: Path | None = None
    """Reuse the label chunks in ``labels_from/<split>`` (and ``/<eval_split>``) as they are, e.g. an earlier run's
    ``OUT/labels``: nothing is simulated and the folder is only read (`load_label_folder`); None simulates (or
    resumes) the labels in ``OUT/labels``."""
    model: dict[str, Any] = overrides_field(ObjectiveConfig)
    """`seal.models.objective.ObjectiveConfig` overrides."""
    train: dict[str, Any] = overrides_field(ObjectiveTrainConfig)
    """`seal.models.objective.ObjectiveTrainConfig` overrides (the seed defaults to ``seed``)."""

    def __post_init__(self) -> None:
        ObjectiveConfig.from_dict(self.model, "config key 'model'")
        ObjectiveTrainConfig.from_dict(self.train, "config key 'train'")
        for key in ("workers", "chunk_size", "n_candidates", "threads"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"config key {key!r} must be >= 1, got {getattr(self, key)}")
        for key in ("limit", "eval_limit"):
            if getattr(self, key) is not None and int(getattr(self, key)) < 1:
                raise ValueError(f"config key {key!r} must be >= 1 or null, got {getattr(self, key)}")
        self.label_behavior()
        if not self.egos:
            raise ValueError("config key 'egos' is empty: give at least one ego (heuristic or a run folder)")
        if (self.prior is None) == (self.candidates is None):
            raise ValueError("give exactly one candidate source: --prior FILE (config key 'prior') or --candidates "
                             "NAME (config key 'candidates', e.g. lanes or constant_velocity)")

    def label_behavior(self) -> Any:
        """The `seal.experiments.fitting.objective_labels.LabelBehavior` of these settings."""
        from seal.experiments.fitting.objective_labels import LabelBehavior

        return LabelBehavior(kind=self.behavior, skills=None if self.skills is None else str(self.skills),
                             switch_offset_steps=int(self.switch_offset_steps), noise_scale=float(self.noise_scale),
                             seed=int(self.seed), adversarial_steps=None if self.adversarial_steps is None
                             else int(self.adversarial_steps))

    def to_dict(self) -> dict[str, Any]:
        """Plain data (the prior path as a string), as recorded in ``config.yaml``."""
        return typing.cast(dict[str, Any], to_dict(self))


def preset_file(name: str) -> Path:
    """The YAML preset ``experiments/configs/objective_<name>.yaml``."""
    return presets.preset_file("objective", name, PRESETS)


def resolve_config(preset: str | None = "standard", config_file: str | Path | None = None, sets: Sequence[str] = (),
                   **values: Any) -> ObjectiveFitConfig:
    """Defaults < preset < YAML config file < ``values`` (None values ignored) < ``sets`` (``key=value``)."""
    return load_config(ObjectiveFitConfig, preset=None if preset is None else preset_file(preset), file=config_file,
                       values=values, overrides=sets)


def labels_for_split(
    dataset: str | Path, split: str, limit: int | None, folder: Path, config: ObjectiveFitConfig, progress: bool,
    start_over: bool = True,
) -> tuple[LabelSet, float]:
    """Build (or resume / reuse) the labels of ``split``'s first ``limit`` scenarios in ``folder`` (with
    ``config.labels_from``: read them from ``labels_from/<split>`` instead); returns the labels and the seconds it
    took. ``start_over``: ``folder`` holding labels of other settings is emptied (else ValueError)."""
    from seal.core.dataset import load_split
    from seal.experiments.fitting.objective_labels import build_labels, load_label_folder, source_spec

    scenarios = load_split(dataset, split, limit)
    if config.labels_from is not None:
        start = time.perf_counter()
        labels = load_label_folder(Path(config.labels_from) / split, [s.scenario_id for s in scenarios],
                                   len(config.egos))
        return labels, round(time.perf_counter() - start, 1)
    spec = source_spec(None if config.prior is None else str(config.prior), config.candidates)
    start = time.perf_counter()
    labels = build_labels(scenarios, folder, spec, n_candidates=config.n_candidates,
                          workers=config.workers, chunk_size=config.chunk_size, progress=progress,
                          desc=f"labels {split}", egos=config.egos, behavior=config.label_behavior(),
                          start_over=start_over)
    return labels, round(time.perf_counter() - start, 1)



def _write_log(path: Path, history: list[dict[str, float]]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=["epoch", "train_loss", "val_loss", "val_spearman", "train_spearman",
                                              "seconds"])
    writer.writeheader()
    writer.writerows(history)
    atomic_write_bytes(path, buf.getvalue().encode())


def fit_objective(dataset: str | Path, out: str | Path, config: ObjectiveFitConfig,
                  progress: bool = True) -> dict[str, Any]:
    """Run the pipeline of the module docstring; returns the report (also in ``out/report.json`` / ``.md``).

    The caller sets torch's threads (the CLI: ``config.threads``); label chunks run on one thread each."""
    from tqdm import tqdm

    from seal.models.objective import train_objective

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(
        {**config.to_dict(), "dataset": str(dataset), "out": str(out)}, sort_keys=True).encode())
    timings: dict[str, float] = {}
    train_labels, timings["labels_train_s"] = labels_for_split(
        dataset, config.split, config.limit, out / "labels" / config.split, config, progress)
    eval_labels, timings["labels_eval_s"] = labels_for_split(
        dataset, config.eval_split, config.eval_limit, out / "labels" / config.eval_split, config, progress)
    overlap = set(train_labels.scenario_ids.tolist()) & set(eval_labels.scenario_ids.tolist())
    if overlap:
        raise ValueError(f"splits {config.split!r} and {config.eval_split!r} share {len(overlap)} scenarios; "
                         "the report must be on held-out scenarios")

    train_cfg = ObjectiveTrainConfig.from_dict({"seed": config.seed, **config.train})
    bar = tqdm(total=train_cfg.max_epochs, desc="training", unit="epoch", disable=not progress)

    def on_step(epoch: int, step: int, steps: float) -> None:
        if step == steps - 1:
            bar.update(1)

    model, fit = train_objective(train_labels, ObjectiveConfig.from_dict(config.model), train_cfg,
                                 on_step=on_step)
    bar.close()
    if config.split == "all-but-eval":  # the diagnosis would otherwise suggest the split this fit already uses
        model.info["fit"]["diagnosis"] = fit_diagnosis(fit, whole_pool=True)
    timings["training_s"] = fit.seconds
    _write_log(out / "train_log.csv", fit.history)
    report = {
        "dataset": str(dataset), "train_split": config.split, "eval_split": config.eval_split,
        "out": str(out), "model": model.config.to_dict(), "fit": model.info.get("fit", {}),
        "train_labels": label_stats(train_labels),
    }
    report.update(evaluate(model, eval_labels, config.seed))
    report["rank_latency"] = rank_latency_ms(model)
    report["timings"] = timings
    source = str(config.prior) if config.prior is not None else config.candidates
    model.info.update({"dataset": str(dataset), "train_split": config.split,
                       "train_scenarios": train_labels.n_scenarios, "candidate_source": source,
                       "held_out": {k: report[k] for k in ("mse", "ranking_logged_prev")}})
    model.save(out / MODEL_FILE)
    write_report(out, report)
    return report


def check_retest(config: ObjectiveFitConfig, retest_seed: int | None, retest_dir: str | Path | None = None) -> None:
    """ValueError unless a second label draw with seed ``retest_seed`` can differ from the first (None: no retest):
    only the ``seal`` label behaviour draws skill noise; replayed candidates against deterministic egos give the
    same labels for every seed. A ``retest_dir`` without a seed is refused too."""
    if retest_seed is None:
        if retest_dir is not None:
            raise ValueError("--retest-labels names the folder of the second label draw: give --retest-seed N too")
        return
    if config.behavior != "seal":
        raise ValueError("--retest-seed: the label behaviour is "
                         f"{config.behavior!r}, whose roll-outs do not depend on the seed (the retest would be 1 by "
                         "construction); use --behavior seal --skills DIR")
    if int(retest_seed) == int(config.seed):
        raise ValueError(f"--retest-seed {retest_seed} is the labels' own seed (--seed {config.seed}); give another")


def eval_objective(model_path: str | Path, dataset: str | Path, config: ObjectiveFitConfig, labels_dir: str | Path,
                   out: str | Path, progress: bool = True, retest_seed: int | None = None,
                   retest_dir: str | Path | None = None) -> dict[str, Any]:
    """Recompute the held-out report of a saved model on ``config.eval_split`` (labels built or reused in
    ``labels_dir``); writes ``report.json`` / ``report.md`` to ``out``. A ``labels_dir`` holding labels of other
    settings (e.g. the model's own, built with another seed or behaviour) is left alone: ValueError.

    With ``retest_seed``, a second draw of the held-out labels (skill-noise seed ``retest_seed``; built or resumed in
    ``retest_dir``, default ``<labels_dir>-seed<retest_seed>``) gives the report's ``label_retest`` section
    (`label_retest`: how far any score could get)."""
    from seal.models.objective import ObjectiveModel

    check_retest(config, retest_seed, retest_dir)
    model = ObjectiveModel.load(model_path)
    labels, seconds = labels_for_split(dataset, config.eval_split, config.eval_limit, Path(labels_dir), config,
                                       progress, start_over=False)
    timings = {"labels_eval_s": seconds}
    second = None
    if retest_seed is not None:
        folder = Path(retest_dir) if retest_dir is not None else Path(labels_dir).with_name(
            f"{Path(labels_dir).name}-seed{retest_seed}")
        draw = dataclasses.replace(config, seed=int(retest_seed), labels_from=None)
        second, timings["labels_retest_s"] = labels_for_split(dataset, config.eval_split, config.eval_limit, folder,
                                                              draw, progress, start_over=False)
    report: dict[str, Any] = {"model_file": str(model_path), "dataset": str(dataset),
                              "eval_split": config.eval_split, "out": str(out), "model": model.config.to_dict()}
    report.update(evaluate(model, labels, config.seed, retest=second))
    report["rank_latency"] = rank_latency_ms(model)
    report["timings"] = timings
    write_report(Path(out), report)
    return report
