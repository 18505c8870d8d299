"""``seal bench env|data|scoring``: speed of the environment, of dataset loading and of scoring."""

from __future__ import annotations

import argparse

from seal.cli.args import CliError, add_set_option, pipeline_choices, positive_int, print_result
from seal.cli.tree import CommandTree


def cmd_bench_data(args: argparse.Namespace) -> int:
    import time

    from seal.core.dataset import Dataset

    start = time.perf_counter()
    scenarios = Dataset.open(args.dir).load(limit=args.n)
    seconds = time.perf_counter() - start
    result = {
        "scenarios_loaded": len(scenarios),
        "seconds": round(seconds, 6),
        "scenarios_per_s": round(len(scenarios) / seconds, 1),
        "target": f"{args.n} scenarios in < 2 s",
        "meets_target": len(scenarios) >= args.n and seconds < 2.0,
    }
    print_result(result, args.json, width=20)
    return 0


def cmd_bench_scoring(args: argparse.Namespace) -> int:
    from seal.scoring.bench import run_scoring_bench

    result = run_scoring_bench(args.dataset, workers=args.workers, limit=args.limit)
    print_result(result, args.json)
    return 0


def cmd_bench_env(args: argparse.Namespace) -> int:
    if args.adversary == "seal":
        from seal.experiments.bench.skills import run_skill_bench

        result = run_skill_bench(args.dataset, skills=args.skills, n_steps=args.steps, seed=args.seed,
                                 repeats=args.repeats)
        print_result(result, args.json)
        return 0
    from seal.experiments.bench.env import run_env_bench

    result = run_env_bench(args.dataset, n_steps=args.steps, seed=args.seed)
    print_result(result, args.json)
    return 0


def cmd_bench_training(args: argparse.Namespace) -> int:
    from seal.experiments.bench.training import run_training_bench
    from seal.experiments.training.config import load_train_config

    over = {"pipeline": args.pipeline, "dataset": args.dataset, "n_envs": args.n_envs, "algo": args.algo}
    if args.prior is not None:
        over["pipelines.cat.kwargs.prior"] = args.prior
        over["pipelines.seal.kwargs.prior"] = args.prior
    if args.ego_skills is not None:
        over["hyperparams.reskill.skills"] = args.ego_skills
    config = load_train_config(args.config, over, sets=args.set)
    import torch

    torch.set_num_threads(int(config["torch_threads"]))
    result = run_training_bench(config, steps=args.steps, progress=not args.json)
    print_result(result, args.json, width=42)
    return 0


def cmd_bench_eval(args: argparse.Namespace) -> int:
    from seal.experiments.bench.evaluation import run_eval_bench

    try:
        result = run_eval_bench(args.dataset, runs=args.runs or ["heuristic"], settings=args.settings,
                                limit=args.limit, workers=args.workers, repeats=args.repeats,
                                candidates=args.candidates, k=args.k)
    except (ValueError, FileNotFoundError) as exc:
        raise CliError(str(exc)) from None
    print_result(result, args.json)
    return 0


def register(tree: CommandTree) -> None:
    bench_sub = tree.group("bench")
    btrain = bench_sub.add_parser(
        "training",
        help="seal train env steps/s with learning vs env only (random actions), estimated 1M-step wall time",
        description="Run the config's training vec env (one closed-loop worker per core, the pipeline's generator "
        "at the curriculum's mean perturbation probability) for --steps env steps with random actions, then train "
        "the config's SB3 model for --steps env steps (gradient updates from the first batch on); print both "
        "steps/s, the generator's share of env time, the cost of a gradient step and the estimated wall time of a "
        "1M-step run (target < 2 h).",
    )
    btrain.add_argument("--config", default="standard",
                        help="preset name (quick | standard | paper) or YAML file with a train: section (default: "
                        "standard, the default preset of seal train)")
    btrain.add_argument("--steps", type=positive_int("--steps"), default=3000, help="env steps per measurement")
    btrain.add_argument("--pipeline", choices=pipeline_choices(), default=None,
                        help="pipeline (default: the config's, cat)")
    btrain.add_argument("--dataset", default=None, help="dataset directory (default: the config's)")
    btrain.add_argument("--prior", default=None, help="trajectory prior for the cat / seal pipelines")
    btrain.add_argument("--n-envs", type=positive_int("--n-envs"), default=None, help="env workers (default: cores)")
    btrain.add_argument("--algo", choices=("td3", "sac", "ppo", "reskill"), default=None,
                        help="ego algorithm (default: the config's, td3)")
    btrain.add_argument("--ego-skills", default=None, help="with --algo reskill: the skills folder (seal fit skills)")
    add_set_option(btrain, "overlap_updates=false (a train: key)")
    btrain.add_argument("--json", action="store_true", help="print JSON (no progress bars)")
    btrain.set_defaults(func=cmd_bench_training)
    benv = bench_sub.add_parser(
        "env",
        help="ScenarioEnv steps/s vs highway-env highway-v0 (10 vehicles, lidar, 10 Hz)",
        description="Measure ScenarioEnv steps/s (full observation, replayed traffic, one process) and, in the "
        "same run, highway-env's highway-v0 with 10 vehicles, LidarObservation, 10 Hz; print both and the ratio.",
    )
    benv.add_argument("--dataset", default=None, help="dataset directory (default: generate a small one in memory)")
    benv.add_argument("--steps", type=positive_int("--steps"), default=3000, help="env steps per measurement")
    benv.add_argument("--seed", type=int, default=0, help="random seed")
    benv.add_argument("--adversary", choices=("replay", "seal"), default="replay",
                      help="replay: ScenarioEnv vs highway-v0 (default); seal: steps/s with the SEAL skill adversary "
                      "vs the replayed adversary in the same run, and the cost ratio (target <= 1.2)")
    benv.add_argument("--skills", default=None,
                      help="with --adversary seal: skills folder from `seal fit skills` (default: untrained models)")
    benv.add_argument("--repeats", type=positive_int("--repeats"), default=3,
                      help="with --adversary seal: identical measurements; each variant's fastest counts (default 3)")
    benv.add_argument("--json", action="store_true", help="print JSON")
    benv.set_defaults(func=cmd_bench_env)
    _register_eval(bench_sub)
    bdata = bench_sub.add_parser(
        "data",
        help="time to open a dataset and load (and validate) N scenarios",
        description="Open a dataset and load its first --n scenarios (checksums and validation included).",
    )
    bdata.add_argument("dir", help="dataset directory")
    bdata.add_argument("--n", type=positive_int("--n"), default=500, help="scenarios to load (default 500)")
    bdata.add_argument("--json", action="store_true", help="print JSON")
    bdata.set_defaults(func=cmd_bench_data)
    bscore = bench_sub.add_parser(
        "scoring",
        help="time to score a dataset with SafeShift (all variants)",
        description="Score a dataset (default: every scenario) without writing anything and print the time per "
        "scenario and in total.",
    )
    bscore.add_argument("dataset", help="dataset directory")
    bscore.add_argument("--workers", type=positive_int("--workers"), default=None, help="processes")
    bscore.add_argument("--limit", type=positive_int("--limit"), default=None, help="score only the first N")
    bscore.add_argument("--json", action="store_true", help="print JSON")
    bscore.set_defaults(func=cmd_bench_scoring)


def _register_eval(bench_sub: argparse._SubParsersAction) -> None:
    beval = bench_sub.add_parser(
        "eval",
        help="seal eval runs episodes/s on N worker processes vs one process, identical rows (target >= 1.8x)",
        description="Evaluate the same egos, settings and scenarios with 1 worker (this process) and with --workers "
        "local worker processes, interleaved --repeats times, each into a fresh results store; print each "
        "variant's episodes/s (rows over the whole evaluation call, the workers' start-up included; and the "
        "steady rate between the first and last row), the speedup and whether the rows are identical.",
    )
    beval.add_argument("runs", nargs="*", help="egos: run folders or built-in egos (default: heuristic); the Replay "
                       "ego is added as by seal eval runs")
    beval.add_argument("--dataset", default=None,
                       help="dataset directory (default: --limit scenarios generated into a temporary folder)")
    beval.add_argument("--settings", default="normal,rule,cat", help="seal eval runs --settings (default: "
                       "normal,rule,cat)")
    beval.add_argument("--limit", type=positive_int("--limit"), default=300,
                       help="scenarios per setting (default 300: the decisive protocol's Normal eval and Hard sizes)")
    beval.add_argument("--workers", type=positive_int("--workers"), default=2,
                       help="worker processes of the parallel variant (default 2)")
    beval.add_argument("--repeats", type=positive_int("--repeats"), default=2,
                       help="measurements per variant, interleaved; the fastest counts (default 2)")
    beval.add_argument("--candidates", choices=("lanes", "constant_velocity"), default="lanes",
                       help="built-in candidate source of candidate-based generators (default lanes: no trained "
                       "prior needed)")
    beval.add_argument("--k", type=positive_int("--k"), default=None,
                       help="perturbation passes of generator settings (default: the eval config's)")
    beval.add_argument("--json", action="store_true", help="print JSON")
    beval.set_defaults(func=cmd_bench_eval)
