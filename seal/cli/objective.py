"""``seal fit objective`` / ``seal eval objective``: SEAL's learned objective pi_score (thesis 6.3.1)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from seal.cli.args import add_fit_job_options, positive_int, set_torch_threads
from seal.cli.tree import CommandTree

if TYPE_CHECKING:
    from seal.experiments.fitting.objective import ObjectiveFitConfig


def _config(args: argparse.Namespace) -> ObjectiveFitConfig:
    from seal.experiments.fitting.objective import resolve_config

    return resolve_config(preset=args.preset, config_file=args.config, sets=args.set, prior=args.prior,
                          candidates=args.candidates, skills=args.skills, behavior=args.behavior,
                          egos=tuple(args.ego) or None, labels_from=args.labels_from,
                          eval_split=args.eval_split, eval_limit=args.eval_limit, workers=args.workers, seed=args.seed,
                          **({"split": args.split, "limit": args.limit} if hasattr(args, "split") else {}))


def cmd_fit_objective(args: argparse.Namespace) -> int:
    import json

    from seal.experiments.fitting.objective import fit_objective
    from seal.experiments.fitting.objective_report import format_summary

    config = _config(args)
    set_torch_threads(config.threads)
    report = fit_objective(args.dataset, args.out, config, progress=not args.no_progress)
    print(json.dumps(report, indent=2, default=str) if args.json else format_summary(report))
    return 0


def cmd_eval_objective(args: argparse.Namespace) -> int:
    import json

    from seal.experiments.fitting.objective import eval_objective
    from seal.experiments.fitting.objective_report import format_report

    model = Path(args.model)
    config = _config(args)
    labels = Path(args.labels) if args.labels else model.parent / "labels" / config.eval_split
    out = Path(args.out) if args.out else model.parent
    report = eval_objective(model, args.dataset, config, labels, out, progress=not args.no_progress,
                            retest_seed=args.retest_seed, retest_dir=args.retest_labels)
    print(json.dumps(report, indent=2, default=str) if args.json else format_report(report))
    return 0


def _common(p: argparse.ArgumentParser) -> None:
    add_fit_job_options(p, "objective", "seal.experiments.fitting.objective.ObjectiveFitConfig",
                        "train.max_epochs=4 or model.hidden=32", "report")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--prior", default=None, help="trajectory prior file (seal fit prior) giving the candidates")
    src.add_argument("--candidates", default=None, choices=("lanes", "constant_velocity"),
                     help="built-in candidate source instead of a prior")
    p.add_argument("--behavior", default=None, choices=("replay", "seal"),
                   help="adversary of the label roll-outs: replay the candidate (default) or SEAL's follow-then-"
                   "skill-switch (needs --skills)")
    p.add_argument("--skills", default=None, help="skills folder (seal fit skills) of --behavior seal")
    p.add_argument("--ego", action="append", default=[],
                   help="ego of the label roll-outs: heuristic or a seal train run folder; repeatable (default "
                   "heuristic)")
    p.add_argument("--eval-split", default=None, help="held-out split of the report (default eval)")
    p.add_argument("--eval-limit", type=positive_int("--eval-limit"), default=None,
                   help="use only the first N held-out scenarios")
    p.add_argument("--workers", type=positive_int("--workers"), default=None,
                   help="processes simulating the labels (default 2)")
    p.add_argument("--labels-from", default=None,
                   help="reuse finished label chunks from DIR/<split> as they are (e.g. an earlier run's OUT/labels): "
                   "no simulation, the folder is only read")


def register(tree: CommandTree) -> None:
    p = tree.group("fit").add_parser(
        "objective",
        help="train SEAL's learned objective pi_score (predicted f_coll, f_diff of candidate adversary futures)",
        description="Roll every trajectory-prior candidate of the adversary (and the logged adversary) out against "
        "the heuristic reactive ego for each scenario of the training split and of the held-out split (resumable "
        "label chunks in OUT/labels/, in parallel), train pi_score (ego roll-out in the candidate's frame per step, "
        "and with model.prev_adversary the previous roll-out's adversary -> polyline encoder -> MLP -> sigmoid "
        "[f_coll, f_diff] as logit "
        "corrections of closeness, MSE, model selection on validation Spearman) and report on the held-out "
        "scenarios: MSE per head, Spearman correlation of the ranking with the simulated f_coll + f_diff, "
        "top-1-in-top-3 rate, against "
        "the closeness / CAT / prior-probability baselines, and rank() latency. Writes objective.pt (+ .json), "
        "report.json, report.md, train_log.csv and config.yaml to --out.",
    )
    _common(p)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--split", default=None, help="split to learn from (default train)")
    p.add_argument("--limit", type=positive_int("--limit"), default=None,
                   help="use only the first N training scenarios")
    p.set_defaults(func=cmd_fit_objective)

    e = tree.group("eval").add_parser(
        "objective",
        help="held-out report (MSE per head, Spearman, top-1-in-top-3, baselines) of a trained pi_score",
        description="Recompute the held-out report of `seal fit objective` for MODEL on DATASET's held-out split: "
        "labels are simulated (or reused from --labels, default MODEL's folder/labels/<split>) with the same "
        "candidate source the model should be judged with.",
    )
    e.add_argument("model", help="objective.pt written by seal fit objective")
    _common(e)
    e.add_argument("--labels", default=None, help="label folder to build or reuse (default MODEL_DIR/labels/SPLIT)")
    e.add_argument("--out", default=None, help="folder for report.json / report.md (default MODEL's folder)")
    e.add_argument("--retest-seed", type=int, default=None,
                   help="also simulate a second draw of the held-out labels with this skill-noise seed (--behavior "
                   "seal) and report how well the two draws rank each other: how much of the label is noise, and "
                   "how far a better score could get")
    e.add_argument("--retest-labels", default=None,
                   help="label folder of the second draw (default: the --labels folder's name + -seed<N>)")
    e.set_defaults(func=cmd_eval_objective)
