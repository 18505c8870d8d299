"""``seal fit prior``, ``seal eval prior``, ``seal bench prior``: the trajectory prior pi_gen."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from seal.cli.args import CliError, add_set_option, positive_float, positive_int, print_result
from seal.cli.tree import CommandTree

#: ``--split`` values besides the dataset's own split names (as `seal.core.dataset`'s, which ``seal --help`` does
#: not import).
ALL = "all"
ALL_BUT_EVAL = "all-but-eval"
HELD_OUT_SPLITS = ("eval", "hard")


def load_split(dataset: str, split: str, limit: int | None = None) -> tuple[list[Any], dict[str, Any]]:
    """Scenarios of ``split`` (`seal.core.dataset.load_split`) and a description of what was loaded."""
    from seal.core.dataset import load_split as load

    try:
        scenarios = load(dataset, split, limit, allow_empty=True)
    except ValueError as exc:
        raise CliError(f"--split {split!r}: {exc}") from None
    info = {"dataset": str(Path(dataset).resolve()), "split": split, "scenarios": len(scenarios)}
    return scenarios, info


def _load_config(path: str | None, values: dict[str, Any],
                 sets: Sequence[str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The ``model`` and ``train`` overrides of the YAML ``--config`` file < named options ``values`` (dotted keys)
    < ``--set``, checked by the loader against `PriorConfig` / `PriorTrainConfig`. The file's dataclass is made
    here, not at module level: its fields name the model classes, whose import pulls in torch."""
    import yaml

    from seal.core.config import load_config, overrides_field
    from seal.models.prior.network import PriorConfig
    from seal.models.prior.train_config import PriorTrainConfig

    @dataclass(frozen=True)
    class PriorFitFile:
        """The ``--config`` file of ``seal fit prior`` (``experiments/configs/prior_default.yaml``)."""

        model: dict[str, Any] = overrides_field(PriorConfig)
        """`PriorConfig` overrides."""
        train: dict[str, Any] = overrides_field(PriorTrainConfig)
        """`PriorTrainConfig` overrides."""

    if path is not None and not Path(path).is_file():
        raise CliError(f"--config: file {path} not found")
    try:
        doc = load_config(PriorFitFile, file=path, values=values, overrides=sets)
    except yaml.YAMLError as exc:
        raise CliError(f"--config: {path} is not valid YAML ({exc})") from None
    return dict(doc.model), dict(doc.train)


def cmd_fit_prior(args: argparse.Namespace) -> int:
    from dataclasses import replace

    import torch

    from seal.core.atomic import atomic_write_json
    from seal.models.prior.network import PriorConfig
    from seal.models.prior.train import PriorTrainConfig, fit_prior

    named = {"epochs": args.epochs, "max_minutes": args.max_minutes, "threads": args.threads, "seed": args.seed}
    model_d, train_d = _load_config(args.config, {f"train.{k}": v for k, v in named.items()}, args.set)
    try:
        model_cfg = PriorConfig.from_dict(model_d)
        train_cfg = PriorTrainConfig.from_dict(train_d)
    except (TypeError, ValueError) as exc:
        raise CliError(f"--config {args.config}: {exc}") from None
    if args.no_time_budget:
        train_cfg = replace(train_cfg, max_minutes=None)
    scenarios, info = load_split(args.dataset, args.split, args.limit)
    info["config_file"] = args.config
    print(f"fit prior: {info['scenarios']} scenarios from {args.dataset} (split {args.split})")
    torch.set_num_threads(train_cfg.threads)  # entry point: the library leaves torch's threads alone
    prior = fit_prior(
        scenarios, args.out, model_cfg, train_cfg, data_info=info, resume=args.resume, progress=not args.no_progress
    )
    summary = {k: v for k, v in prior.training.items() if not k.endswith("_scenario_ids")}
    sidecar = Path(str(args.out) + ".json")
    atomic_write_json(sidecar, {"model_config": prior.config.to_dict(), "training": summary})
    print(f"wrote {args.out} and {sidecar} (resolved config and training summary)")
    return 0


def _fmt(v: float) -> str:
    return f"{v:.3f}"


def _print_eval(res: dict[str, Any]) -> None:
    print(f"scenarios: {res['scenarios']} (seen in training: {res['scenarios_seen_in_training']}), "
          f"miss threshold {res['miss_threshold_m']} m on minFDE@6 at 8 s")
    for kind in ("adversary", "moving"):
        if kind not in res:
            continue
        r = res[kind]
        print(f"\n[{kind}] {r['targets']} targets with a full 8 s future "
              f"({r['fallbacks']} constant-velocity fallbacks)")
        print(f"  {'':<22}{'@1':>9}{'@6':>9}{'@32':>9}")
        print(f"  {'minADE (m)':<22}" + "".join(f"{r[f'min_ade_{k}']:>9.3f}" for k in (1, 6, 32)))
        print(f"  {'minFDE (m)':<22}" + "".join(f"{r[f'min_fde_{k}']:>9.3f}" for k in (1, 6, 32)))
        print(f"  miss rate (minFDE@6)   {r['miss_rate_6']:.3f}")
        print(f"  constant velocity      ADE {_fmt(r['cv_ade'])} m, FDE {_fmt(r['cv_fde'])} m, "
              f"miss rate {r['cv_miss_rate']:.3f}")
        verdict = "meets" if r["meets_target"] else "MISSES"
        print(f"  minADE@6 / CV ADE      {r['ratio_min_ade_6_to_cv_ade']:.3f}  (target <= 0.5: {verdict})")
        print(f"  candidates within |acc| <= 8 m/s^2: {r['share_within_acc']:.4f}, |yaw rate| <= 1 rad/s: "
              f"{r['share_within_yaw_rate']:.4f}")
        if "share_drivable" in r:
            print(f"  candidates on or near the road: {r['share_on_road']:.4f}; drivable (all three): "
                  f"{r['share_drivable']:.4f} (target >= 0.95), top-6 only {r['share_drivable_top6']:.4f}")
            print(f"  strict map (lanes end at the map edge): on road {r['share_on_road_strict']:.4f}, drivable "
                  f"{r['share_drivable_strict']:.4f}")
            print(f"  logged futures for reference: within acc {r['logged_share_within_acc']:.3f}, within yaw rate "
                  f"{r['logged_share_within_yaw_rate']:.3f}, on road {r['logged_share_on_road']:.3f}")
        print("  per layout (minADE@6 / CV ADE, m): " + ", ".join(
            f"{name} {v['min_ade_6']:.2f}/{v['cv_ade']:.2f} (n={v['targets']})" for name, v in r["per_layout"].items()
        ))


def cmd_eval_prior(args: argparse.Namespace) -> int:
    import torch

    from seal.models.prior.evaluate import evaluate_prior
    from seal.models.prior.prior import TrajectoryPrior

    prior = TrajectoryPrior.load(args.model)
    scenarios, _ = load_split(args.dataset, args.split, args.limit)
    if not scenarios:
        raise CliError(f"--split {args.split}: no scenarios")
    kinds = ("adversary", "moving") if args.targets == "both" else (args.targets,)
    torch.set_num_threads(args.threads)
    res = evaluate_prior(
        prior, scenarios, kinds=kinds, miss_threshold_m=args.miss_threshold_m, check_road=not args.no_road,
        progress=not args.no_progress and not args.json,
    )
    res = {"model": str(args.model), "dataset": str(args.dataset), "split": args.split, **res}
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        _print_eval(res)
    return 0


def cmd_bench_prior(args: argparse.Namespace) -> int:
    import torch

    from seal.models.prior.bench import bench_prior
    from seal.models.prior.prior import TrajectoryPrior

    if args.model is not None:
        prior = TrajectoryPrior.load(args.model)
        weights = str(args.model)
    else:
        prior = TrajectoryPrior.untrained()
        weights = "random init, default config (latency does not depend on the weights)"
    if args.dataset is not None:
        scenarios, _ = load_split(args.dataset, ALL, limit=max(args.batch, 64))
        source = f"dataset {args.dataset}"
    else:
        from seal.experiments.bench.env import bench_scenarios

        scenarios, source = bench_scenarios(None, seed=0, n_runs=8)
    torch.set_num_threads(args.threads)
    res = bench_prior(prior, scenarios, repeats=args.repeats, batch=args.batch)
    print_result({"model": weights, "scenarios": source, **res}, args.json)
    return 0


def register(tree: CommandTree) -> None:
    fit = tree.group("fit").add_parser(
        "prior",
        help="train the trajectory prior pi_gen (32 candidate 8 s futures per agent)",
        description="Train the trajectory prior on every moving agent of the chosen scenarios (validation on a "
        "held-out share of them by scenario, early stopping, best epoch kept). The model file records the "
        "model config and a training summary; FILE.json repeats them for humans. CPU only.",
    )
    fit.add_argument("dataset", help="dataset directory")
    fit.add_argument("--out", required=True, help="model file to write (e.g. runs/prior.pt)")
    fit.add_argument(
        "--split", default="train",
        help=f"scenarios to train on: a split name (default: train), '{ALL}', or '{ALL_BUT_EVAL}' (every "
        f"scenario outside the {' and '.join(HELD_OUT_SPLITS)} splits)",
    )
    fit.add_argument("--config", default=None, help="YAML with 'model' and 'train' sections "
                     "(e.g. experiments/configs/prior_default.yaml); default: built-in defaults")
    fit.add_argument("--epochs", type=positive_int("--epochs"), default=None, help="maximum epochs")
    fit.add_argument("--max-minutes", type=positive_float("--max-minutes"), default=None,
                     help="wall-clock budget, data preparation included; epochs are planned to fit it (default 12)")
    fit.add_argument("--no-time-budget", action="store_true", help="no budget (fully deterministic for a seed)")
    fit.add_argument("--threads", type=positive_int("--threads"), default=None, help="torch CPU threads (default 1)")
    fit.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    fit.add_argument("--limit", type=positive_int("--limit"), default=None, help="use only the first N scenarios")
    fit.add_argument("--resume", action="store_true", help="continue an interrupted run with the same --out")
    fit.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    add_set_option(fit, "train.road_weight=1.0 or model.n_modes=16")
    fit.set_defaults(func=cmd_fit_prior)

    ev = tree.group("eval").add_parser(
        "prior",
        help="minADE / minFDE @1/6/32, miss rate and drivability of a prior vs constant velocity",
        description="Evaluate a trained prior on a split (default: eval): minADE / minFDE at 1, 6 and 32 "
        "candidates, miss rate, the share of drivable candidates, and the constant-velocity baseline measured "
        "in the same run, for the adversaries and for all moving agents with a full 8 s future.",
    )
    ev.add_argument("model", help="model file from `seal fit prior`")
    ev.add_argument("dataset", help="dataset directory")
    ev.add_argument("--split", default="eval", help=f"split name, '{ALL}' or '{ALL_BUT_EVAL}' (default: eval)")
    ev.add_argument("--targets", choices=("adversary", "moving", "both"), default="both", help="default: both")
    ev.add_argument("--miss-threshold-m", type=positive_float("--miss-threshold-m"), default=2.0,
                    help="a target is missed when minFDE@6 exceeds this (m, default 2)")
    ev.add_argument("--no-road", action="store_true", help="skip the on-road check (faster)")
    ev.add_argument("--limit", type=positive_int("--limit"), default=None, help="only the first N scenarios")
    ev.add_argument("--threads", type=positive_int("--threads"), default=1, help="torch CPU threads (default 1)")
    ev.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    ev.add_argument("--json", action="store_true", help="print JSON")
    ev.set_defaults(func=cmd_eval_prior)

    bench = tree.group("bench").add_parser(
        "prior",
        help="latency of 32 candidates for one scenario and for a batch of 64 (CPU)",
        description="Median latency of TrajectoryPrior.predict (featurisation included) for one scenario and "
        "for a batch of scenarios, after warm-up; target: under 10 ms for one scenario.",
    )
    bench.add_argument("--model", default=None, help="model file (default: random weights, same latency)")
    bench.add_argument("--dataset", default=None, help="dataset directory (default: generate a few in memory)")
    bench.add_argument("--repeats", type=positive_int("--repeats"), default=50, help="timed calls (default 50)")
    bench.add_argument("--batch", type=positive_int("--batch"), default=64, help="batch size (default 64)")
    bench.add_argument("--threads", type=positive_int("--threads"), default=1, help="torch CPU threads (default 1)")
    bench.add_argument("--json", action="store_true", help="print JSON")
    bench.set_defaults(func=cmd_bench_prior)
