"""``seal eval generators`` and ``seal bench generators``: compare adversary generators and time them."""

from __future__ import annotations

import argparse

from seal.cli.args import CliError, add_plugin_option, non_negative_int, positive_int, print_result
from seal.cli.tree import CommandTree


def _generator_options(args: argparse.Namespace) -> tuple[dict, dict]:
    """(resolved config, shared generator options) from the command line; bad generator names -> CliError."""
    from seal.experiments.evaluation.generators import resolve_config

    try:
        config = resolve_config(
            args.config, generators=args.generators, ego=getattr(args, "ego", None), algo=getattr(args, "algo", None),
            split=args.split, limit=args.limit, offset=getattr(args, "offset", None), k=getattr(args, "k", None),
            seed=args.seed, prior=args.prior, candidates=args.candidates, objective=args.objective, skills=args.skills,
            gen_opts=args.gen_opt,
        )
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if args.all_scenarios:
        config["split"] = None
    return config, {key: config[key] for key in ("prior", "candidates", "objective", "skills")}


def _prior_threads_if_needed(config: dict, shared: dict) -> None:
    """Entry point's torch threads: `PRIOR_THREADS` when a configured generator reads a trajectory prior file (what
    loading the prior did before the library stopped setting threads); else torch's setting stays."""
    import torch

    from seal.adversaries.base import generator_class
    from seal.adversaries.candidate_generator import CandidateGenerator
    from seal.adversaries.candidate_sources import PRIOR_THREADS
    from seal.experiments.evaluation.generators import generator_name

    for name, kw in config["generators"].items():
        cls = generator_class(generator_name(name, kw))
        prior = kw["prior"] if "prior" in kw else shared.get("prior")  # as build_generator merges them
        if isinstance(cls, type) and issubclass(cls, CandidateGenerator) and prior is not None:
            torch.set_num_threads(PRIOR_THREADS)
            return


def cmd_eval_generators(args: argparse.Namespace) -> int:
    from seal.experiments.evaluation.generator_metrics import markdown_table
    from seal.experiments.evaluation.generators import run_eval_generators

    config, shared = _generator_options(args)
    _prior_threads_if_needed(config, shared)
    rows = run_eval_generators(args.dataset, args.out, config, progress=not args.no_progress)
    print(markdown_table(rows))
    print(f"wrote {args.out}/generators.md, generators.csv, generators.json, episodes.csv and config.yaml")
    return 0


def cmd_bench_generators(args: argparse.Namespace) -> int:
    import torch

    from seal.adversaries.candidate_generator import uses_prior_file
    from seal.adversaries.candidate_sources import PRIOR_THREADS
    from seal.core.dataset import load_split
    from seal.experiments.bench.generators import bench_generators, format_bench
    from seal.experiments.evaluation.protocol import build_generator

    config, shared = _generator_options(args)
    scenarios = load_split(args.dataset, config["split"], config["limit"] or args.n)
    generators = {name: build_generator(name, kw, shared) for name, kw in config["generators"].items()}
    if uses_prior_file(generators.values()):
        torch.set_num_threads(PRIOR_THREADS)  # entry point: the library leaves torch's threads alone
    result = bench_generators(scenarios, generators, seed=config["seed"])
    if args.json:
        print_result(result, True)
    else:
        print(format_bench(result))
    return 0


def _common(p: argparse.ArgumentParser, default_generators: str) -> None:
    p.add_argument("dataset", help="dataset directory (seal data generate / score / split)")
    p.add_argument(
        "--generators", default=None,
        help=f"comma-separated generator names (default {default_generators}); e.g. replay,rule,cat,goose; with "
             "--config, labels of its generators entries pick those configurations (e.g. cat,seal_traj_only)",
    )
    p.add_argument("--split", default=None, help="dataset split to use (default eval)")
    p.add_argument("--all-scenarios", action="store_true", help="ignore splits, use every scenario")
    p.add_argument("--limit", type=positive_int("--limit"), default=None, help="only the first N scenarios")
    p.add_argument("--prior", default=None, help="trajectory prior file for candidate-based generators (cat)")
    p.add_argument(
        "--candidates", default=None,
        help="built-in candidate source instead of a prior: lanes (map-based heuristic) or constant_velocity",
    )
    p.add_argument("--objective", default=None,
                   help="seal: learned objective file (seal fit objective) or 'cat' for CAT's heuristic selection")
    p.add_argument("--skills", default=None, help="seal: skill model folder (seal fit skills)")
    p.add_argument(
        "--gen-opt", action="append", default=[], metavar="NAME.KEY=VALUE",
        help="constructor option of one generator, repeatable, e.g. goose.model=agent.pt or cat.follow=track",
    )
    p.add_argument("--config", default=None, help="YAML config (keys as in "
        "seal.experiments.evaluation.generators.EvalGeneratorsConfig)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    add_plugin_option(p)


def register(tree: CommandTree) -> None:
    ev = tree.group("eval").add_parser(
        "generators",
        help="X-Gen evaluation of adversary generators against one ego (Table 6.2 columns)",
        description="For every scenario: one normal episode, then K sequential perturbation passes per generator "
        "against the same ego (each roll-out appended to the scenario's queue); the last pass is scored. Writes "
        "generators.{md,csv,json}, episodes.csv and the resolved config.yaml into --out.",
    )
    _common(ev, "replay,rule,cat")
    ev.add_argument(
        "--ego", default=None,
        help="heuristic | replay | a seal run folder, checkpoint or any SB3 model .zip (VecNormalize stats beside "
        "it are applied) | an installed seal.egos entry point; default replay",
    )
    ev.add_argument("--algo", default=None, help="SB3 algorithm of an --ego model file that does not record it "
                    "(td3 | sac | ppo | ddpg | a2c; default: read from the file)")
    ev.add_argument("--k", type=positive_int("--k"), default=None, help="perturbation passes = queue length (5)")
    ev.add_argument("--offset", type=non_negative_int("--offset"), default=None,
                    help="skip the first N scenarios of the split (a held-out slice; each scenario keeps the "
                    "episodes it gets in a run over the whole split)")
    ev.add_argument("--out", required=True, help="output folder")
    ev.add_argument("--no-progress", action="store_true", help="no progress bar")
    ev.set_defaults(func=cmd_eval_generators)

    bench = tree.group("bench").add_parser(
        "generators",
        help="generation latency per scenario (batch of one, CPU) vs the 30 ms real-time budget",
        description="Time each generator's generate() on N scenarios (queue: K copies of the logged ego future, "
        "one warm-up call), twice per scenario: print mean / p50 / p95 / max ms of the first (cold) call, mean / "
        "p95 of the second (warm) call, CAT's candidate (pi_gen) and selection shares, and the ratio to replay "
        "measured in the same run.",
    )
    _common(bench, "replay,rule,cat")
    bench.add_argument("--n", type=positive_int("--n"), default=100, help="scenarios to time (default 100)")
    bench.add_argument("--json", action="store_true", help="print JSON")
    bench.set_defaults(func=cmd_bench_generators)
