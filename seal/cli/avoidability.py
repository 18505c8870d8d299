"""``seal eval avoidability``: which of an ego's crashes in a setting some other ego plan avoids (hindsight search)."""

from __future__ import annotations

import argparse
import os

from seal.cli.args import CliError, add_plugin_option, non_negative_int, positive_int
from seal.cli.evaluate import add_eval_config_options, eval_config_from_args
from seal.cli.tree import CommandTree

PLAN_SPACES = ("actions", "skills")
"""`seal.experiments.evaluation.avoidance_plans.PLAN_SPACES`, named here so that ``--help`` imports no simulator
(a test keeps the two equal)."""


def cmd_eval_avoidability(args: argparse.Namespace) -> int:
    import csv
    import dataclasses
    import io
    import json
    from pathlib import Path

    from seal.core.atomic import atomic_write_bytes, atomic_write_json
    from seal.experiments.evaluation import avoidability as av
    from seal.experiments.evaluation.evaluate import default_dataset, parse_settings, read_run

    try:
        ego = read_run(args.ego, args.algo)
        config = eval_config_from_args(args, [ego.config])
        (setting,) = parse_settings([args.setting], args.dataset or default_dataset([ego]))
        search = av.AvoidabilityConfig(n_plans=args.plans, seed=args.plan_seed, plan_space=args.plan_space)
        if search.plan_space == "skills" and str(ego.algo or "").lower() != "reskill":
            raise ValueError(f"--plan-space skills: {args.ego} is not a ReSkill ego (algo {ego.algo or 'none'}); the "
                             "skills space searches a ReSkill ego's own skill choices")
    except (ValueError, RuntimeError, FileNotFoundError) as exc:
        raise CliError(str(exc)) from None
    out = Path(args.out) if args.out else None
    if out is not None and out.exists() and not out.is_dir():
        raise CliError(f"--out {out}: exists and is not a directory")
    workers = args.workers or os.cpu_count() or 1
    rows = av.run_avoidability(ego.ego, setting, config, search, algo=ego.algo, progress=not args.no_progress,
                               workers=workers)
    summary = {"ego": ego.ego, "setting": setting.name, "search": dataclasses.asdict(search),
               "k": int(config["k"]), "seed": int(config["seed"]), **av.summarize(rows)}
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        buf = io.StringIO()
        table = av.row_dicts(rows)
        writer = csv.DictWriter(buf, fieldnames=list(table[0]) if table else ["scenario_id"])
        writer.writeheader()
        writer.writerows(table)
        atomic_write_bytes(out / "avoidability.csv", buf.getvalue().encode())
        atomic_write_json(out / "summary.json", summary)
    print(json.dumps(summary, indent=2) if args.json else av.format_summary(summary, ego.ego, setting.name))
    if out is not None and not args.json:
        print(f"per scenario: {out / 'avoidability.csv'}; summary: {out / 'summary.json'}")
    return 0


def register(tree: CommandTree) -> None:
    p = tree.group("eval").add_parser(
        "avoidability",
        help="were an ego's crashes in a setting avoidable? replay each crash's adversary against other ego plans",
        description="Play the ego on a setting as `seal eval runs` does (normal episode, K generator passes, the "
        "last scored). For each scored episode that ends in a crash, play the same adversary again (same env seed) "
        "against the heuristic driver and --plans plans that add piecewise-constant offsets to its acceleration "
        "and steering (full braking / full throttle from each sixth of the horizon on, then random). A crash is "
        "avoidable when some plan ends without a crash and on the road; the plans know the adversary's future, so "
        "this is a hindsight bound, and 'not avoidable' means none of the plans tried avoided it. --plan-space skills "
        "searches a ReSkill ego's own skill space instead (its agent with its skill choices changed: the hardest "
        "braking / throttling skill from each sixth on, then random offsets on its high-level action), which says "
        "whether its crashes are a limit of its skills or of what it learned. Crashes are split "
        "by whom the ego touched (the adversary, or other traffic replaying its log). Writes --out DIR/"
        "avoidability.csv (per scenario) and summary.json.",
    )
    p.add_argument("ego", help="run folder, model .zip, 'heuristic' or an installed seal.egos entry point")
    p.add_argument("--setting", required=True,
                   help="one setting: normal, hard, normal-reactive, a generator name (cat, seal, ...) or real:DIR")
    p.add_argument("--algo", default=None, help="SB3 algorithm of a model file that does not record it")
    add_plugin_option(p)
    p.add_argument("--dataset", default=None,
                   help="dataset with eval / hard splits (default: the 'dataset' of the run's config.yaml)")
    add_eval_config_options(p)
    p.add_argument("--plans", type=non_negative_int("--plans"), default=64,
                   help="ego plans tried per crash besides the heuristic driver (default 64)")
    p.add_argument("--plan-seed", type=int, default=0, help="seed of the random plans (default 0)")
    p.add_argument("--plan-space", choices=PLAN_SPACES, default="actions",
                   help="actions: plans around the heuristic driver in the env's action space (default); skills: "
                   "plans in a ReSkill ego's skill space")
    p.add_argument("--workers", type=positive_int("--workers"), default=None,
                   help="worker processes over which the scenarios are spread (default: the CPU count; 1 = in this "
                   "process); the rows are the same for any count")
    p.add_argument("--out", default=None, help="folder for avoidability.csv and summary.json")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_eval_avoidability)
