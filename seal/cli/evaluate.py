"""``seal eval runs``: evaluate trained egos (plus the Replay ego) on Normal, Hard, X-Gen and real-data settings,
results into the SQLite results store.

It is the ``eval`` group's default subcommand: ``seal eval RUN...`` means ``seal eval runs RUN...`` whenever the first
word is not another ``eval`` subcommand (``prior``, ``generators``, ``objective``); a run folder with such a name
needs the explicit ``seal eval runs`` form (`seal.cli.tree.CommandTree.set_default`).
"""

from __future__ import annotations

import argparse
import os
from typing import Any

from seal.cli.args import CliError, add_plugin_option, add_set_option, positive_int
from seal.cli.tree import CommandTree

# What an evaluation worker imports before its first chunk: started with the pool (`LocalBackend.start`), so that
# it overlaps this process's own imports and planning.
WORKER_WARM_MODULES = ("seal.experiments.evaluation.parallel", "seal.experiments.evaluation.protocol",
                       "seal.envs.scenario_env", "seal.envs.heuristic")


def cmd_eval_runs(args: argparse.Namespace) -> int:
    from seal.experiments.backends import Backend, LocalBackend, make_backend

    workers = args.workers or os.cpu_count() or 1
    backend: Backend | None = None
    if args.backend != "ray" and workers > 1:
        # Spawn the workers first: their start-up then runs while this process imports and plans.
        backend = LocalBackend(workers, warm=WORKER_WARM_MODULES).start()
    try:
        from seal.experiments.evaluation.evaluate import read_run
        from seal.experiments.evaluation.parallel import evaluate_runs

        runs = [*args.runs, *args.ego]
        try:
            egos = [read_run(r, args.algo) for r in runs]
            config = eval_config_from_args(args, [e.config for e in egos])
            if args.backend == "ray":
                backend = make_backend("ray", address=args.address, ray_local_cpus=args.ray_local_cpus)
        except (ValueError, RuntimeError, FileNotFoundError) as exc:
            raise CliError(str(exc)) from None
        results = evaluate_runs(
            runs, args.settings, args.store, dataset=args.dataset, config=config,
            replay_ego=not args.no_replay_ego, workers=workers, progress=not args.no_progress, backend=backend,
            algo=args.algo,
        )
    finally:
        if backend is not None:
            backend.shutdown()  # type: ignore[attr-defined]
    for r in results:
        written = ", ".join(f"{s}: {n}" for s, n in r["written"].items())
        print(f"{r['run']}: new episodes {written}")
    print(f"results in {args.store} (seal compare --store {args.store} --out REPORT_DIR)")
    return 0


def add_eval_config_options(p: argparse.ArgumentParser) -> None:
    """The evaluation protocol's options (`eval_config_from_args`): --limit, --k, --seed, --config, --set, --prior,
    --candidates, --gen-opt."""
    p.add_argument("--limit", type=positive_int("--limit"), default=None, help="first N scenarios of each split")
    p.add_argument("--k", type=positive_int("--k"), default=None, help="perturbation passes = queue length (5)")
    p.add_argument("--seed", type=int, default=None, help="episode / generator rng seed, same for every ego (0)")
    p.add_argument("--config", default=None,
                   help="YAML with generators kwargs (generators: {goose: {model: F}, cat: {prior: F}}), prior, "
                   "candidates, k, limit, seed, env; a `seal run` preset's eval section also works. Default: the "
                   "generator kwargs recorded in the runs' config.yaml")
    add_set_option(p, "k=3 or generators.cat.stride=10")
    p.add_argument("--prior", default=None, help="trajectory prior for candidate-based generators (cat, seal)")
    p.add_argument("--candidates", default=None, help="built-in candidate source instead of a prior: lanes | "
                   "constant_velocity")
    p.add_argument("--gen-opt", action="append", default=[], metavar="NAME.KEY=VALUE",
                   help="constructor option of one generator, repeatable, e.g. goose.model=goose.zip")


def eval_config_from_args(args: argparse.Namespace, run_configs: list[dict[str, Any]]) -> dict[str, Any]:
    """The resolved evaluation config of `add_eval_config_options`' options (`resolve_eval_config`, then each
    --gen-opt); raises ValueError naming a bad option."""
    from seal.experiments.evaluation.evaluate import resolve_eval_config
    from seal.experiments.evaluation.generators import apply_generator_options

    config = resolve_eval_config(args.config, run_configs=run_configs, k=args.k, limit=args.limit, seed=args.seed,
                                 prior=args.prior, candidates=args.candidates, sets=args.set)
    for option in args.gen_opt:
        config["generators"].setdefault(option.partition(".")[0], {})
    apply_generator_options(config["generators"], args.gen_opt)
    return config


def register(tree: CommandTree) -> None:
    tree.set_default("eval", "runs")  # `seal eval RUN... --settings ...`, the protocol's command
    p = tree.group("eval").add_parser(
        "runs",
        help="evaluate trained egos (+ Replay ego) on normal / hard / X-Gen / real:DIR settings into a results store",
        description="Evaluate each RUN folder (config.yaml + final_model.zip, from `seal train` / `seal run`) and, "
        "unless --no-replay-ego, the Replay ego (logged ego replayed open loop). Settings: normal (eval split, "
        "logged adversary), hard (hard split), a generator name such as cat, goose, seal, rule (the Normal eval "
        "scenarios: one normal episode, then K sequential perturbation passes against the same ego, the last "
        "scored), normal-reactive (normal with reacting background traffic: --set background=idm, or "
        "background=rapid with background_model=FILE), GENERATOR-reactive (a generator setting with that "
        "background), real:DIR (an imported dataset, its eval split or every "
        "scenario, logged adversary). One row per "
        "(run, dataset, setting, scenario) goes into the SQLite --store; scenarios already there are skipped, so "
        "re-running adds only what is missing.",
    )
    p.add_argument("runs", nargs="*", metavar="RUN",
                   help="run folders, checkpoints (RUN/checkpoints/step_N/model.zip), any SB3 model .zip, "
                   "'heuristic' or an installed seal.egos entry point; none = only the Replay ego")
    p.add_argument("--ego", action="append", default=[], metavar="EGO",
                   help="one more ego, as RUN (repeatable; e.g. --ego my_sac.zip --algo sac)")
    p.add_argument("--algo", default=None, help="SB3 algorithm of model files that do not record it "
                   "(td3 | sac | ppo | ddpg | a2c; default: read from the file or its run's config.yaml)")
    add_plugin_option(p)
    p.add_argument("--settings", default="normal,hard",
                   help="comma-separated: normal, hard, normal-reactive, GENERATOR (cat, goose, seal, rule, replay), "
                   "GENERATOR-reactive (with the reactive background of normal-reactive), real:DIR "
                   "(default normal,hard)")
    p.add_argument("--store", default="results.sqlite", help="SQLite results store (default results.sqlite)")
    p.add_argument("--dataset", default=None,
                   help="dataset with eval / hard splits (default: the 'dataset' of the first run's config.yaml)")
    add_eval_config_options(p)
    p.add_argument("--no-replay-ego", action="store_true", help="do not evaluate the Replay ego")
    p.add_argument("--workers", type=positive_int("--workers"), default=None,
                   help="local worker processes over which egos x scenarios are spread, in chunks of a few "
                   "scenarios (default: the CPU count; 1 = in this process); the rows are the same for any count")
    p.add_argument("--backend", choices=("local", "ray"), default="local",
                   help="local: --workers processes on this machine (default); ray: Ray tasks on a running cluster "
                   "(--address, RAY_ADDRESS or auto) or on a private local instance (--ray-local-cpus)")
    p.add_argument("--address", default=None, help="with --backend ray: the cluster address")
    p.add_argument("--ray-local-cpus", type=positive_int("--ray-local-cpus"), default=None,
                   help="with --backend ray: start a private local Ray instance of N CPUs instead of connecting")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_eval_runs)
