"""``seal fit goose``: train the GOOSE adversary agent (SB3 SAC/TD3 + HER against the heuristic reactive ego)."""

from __future__ import annotations

import argparse

from seal.cli.args import add_fit_job_options, positive_int, set_torch_threads
from seal.cli.tree import CommandTree


def cmd_fit_goose(args: argparse.Namespace) -> int:
    import dataclasses
    import json

    from seal.experiments.fitting.goose import FIT_THREADS, fit_goose, format_summary, resolve_config

    config = resolve_config(
        preset=args.preset, config_file=args.config, sets=args.set, algo=args.algo, total_steps=args.steps,
        seed=args.seed, split=args.split, limit=args.limit, eval_split=args.eval_split, eval_limit=args.eval_limit,
    )
    if args.no_eval:
        config = dataclasses.replace(config, eval_split=None)
    set_torch_threads(FIT_THREADS)
    summary = fit_goose(args.dataset, args.out, config, run_dir=args.run_dir, progress=not args.no_progress)
    print(json.dumps(summary, indent=2, default=str) if args.json else format_summary(summary))
    return 0


def register(tree: CommandTree) -> None:
    p = tree.group("fit").add_parser(
        "goose",
        help="train the GOOSE agent (NURBS edits of the adversary path, SAC/TD3 + HER) on a dataset split",
        description="Train GOOSE's goal-conditioned agent: each episode is one scenario, each step one curve update "
        "of the adversary's NURBS path followed by a roll-out of the heuristic reactive ego (goal 'deceleration': "
        "contact with |acc| <= 8 m/s^2, |yaw rate| <= 0.7 rad/s, at most K = 5 updates). Writes the agent file "
        "--out (use it as `goose` generator model=FILE) and a run folder (config.yaml, progress.csv, success.csv, "
        "eval.json, summary.json); then reports held-out goal success against zero / random / untrained policies.",
    )
    add_fit_job_options(p, "goose", "seal.experiments.fitting.goose.GooseFitConfig",
                        "spec.max_updates=3 or net_arch=[64,64]", "summary")
    p.add_argument("--out", required=True, help="agent file to write (.zip)")
    p.add_argument("--algo", choices=("sac", "td3"), default=None, help="RL algorithm (default from the preset: sac)")
    p.add_argument("--steps", type=positive_int("--steps"), default=None, help="training roll-outs (env steps)")
    p.add_argument("--split", default=None, help="training split (default train)")
    p.add_argument("--limit", type=positive_int("--limit"), default=None,
                   help="use only the first N training scenarios")
    p.add_argument("--eval-split", default=None, help="held-out split for the final check (default eval)")
    p.add_argument("--eval-limit", type=positive_int("--eval-limit"), default=None,
                   help="held-out scenarios to check (default: preset)")
    p.add_argument("--no-eval", action="store_true", help="skip the held-out check")
    p.add_argument("--run-dir", default=None, help="run folder (default: OUT without suffix + '_run')")
    p.set_defaults(func=cmd_fit_goose)
