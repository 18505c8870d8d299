"""``seal demo``, ``seal render`` and the ``seal data`` commands that build, score, split and inspect datasets."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from seal.cli.args import LAYOUTS, CliError, add_plugin_option, layouts, non_negative_int, positive_int, share
from seal.cli.tree import CommandTree


def cmd_data_generate(args: argparse.Namespace) -> int:
    from seal.envs.generate import generate_dataset

    layouts = [name for group in args.layouts for name in group]
    ds = generate_dataset(
        args.out,
        n=args.n,
        seed=args.seed,
        layouts=layouts,
        workers=args.workers,
        inattentive_share=args.inattentive_share,
        aggressive_share=args.aggressive_share,
        overwrite=args.overwrite,
        progress=not args.no_progress,
    )
    print(f"wrote {len(ds)} scenarios to {ds.root}")
    _print_info(ds.root, as_json=False)
    return 0


def _print_info(root: Path, as_json: bool) -> None:
    from seal.core.dataset import Dataset, summarize
    from seal.scoring.proximity import pool_proximity

    ds = Dataset.open(root)
    scenarios = ds.load()
    info = summarize(scenarios)
    split_of = {sid: name for name, ids in ds.splits.items() for sid in ids}
    per_split: dict[str, dict[str, int]] = {}
    for s in scenarios:
        row = per_split.setdefault(split_of.get(s.scenario_id, "unsplit"), {})
        row[s.layout] = row.get(s.layout, 0) + 1
    info["per_split_layout"] = per_split
    info["proximity"] = pool_proximity(scenarios)
    info["provenance"] = ds.manifest["provenance"]
    if as_json:
        print(json.dumps(info, indent=2, sort_keys=True))
        return
    print(f"dataset {root}: {info['scenarios']} scenarios")
    layouts = sorted(info["per_layout"])
    print(f"  {'split':<10}" + "".join(f"{name:>14}" for name in layouts) + f"{'total':>10}")
    for split, row in sorted(per_split.items()):
        cells = "".join(f"{row.get(name, 0):>14}" for name in layouts)
        print(f"  {split:<10}{cells}{sum(row.values()):>10}")
    for key, label in (("agents_per_scenario", "agents per scenario"), ("track_length_steps", "valid steps/track")):
        st = info[key]
        print(f"  {label:<22} mean {st['mean']:.1f}  min {st['min']:.0f}  median {st['p50']:.0f}  max {st['max']:.0f}")
    p = info["proximity"]
    print(
        f"  (ego, adv) pair: within 2 m {p['pair_within_2m']:.1%}, within 5 m {p['pair_within_5m']:.1%}, "
        f"collision {p['pair_collision']:.1%}; scenarios with any collision {p['any_collision']:.1%}"
    )


def cmd_data_info(args: argparse.Namespace) -> int:
    _print_info(Path(args.dir), as_json=args.json)
    return 0


def cmd_data_score(args: argparse.Namespace) -> int:
    from seal.scoring.store import score_dataset

    summary = score_dataset(args.dir, workers=args.workers, progress=not args.no_progress)
    print(json.dumps(summary, indent=2, default=str))
    return 0


def cmd_data_split(args: argparse.Namespace) -> int:
    from seal.scoring.splits import make_splits

    result = make_splits(
        args.dir,
        hard_quantile=args.hard_quantile,
        n_train=args.n_train,
        n_eval=args.n_eval,
        n_hard=args.n_hard,
        seed=args.seed,
        score=args.score,
        hard_by=args.hard_by,
    )
    if args.json:
        print(json.dumps(result, indent=2, default=str))
        return 0
    print(
        f"splits of {args.dir} (Hard by {result['hard_by']}, {result['score'].upper()} score above "
        f"{result['threshold']:.3f}): train {result['train']}, eval {result['eval']}, hard {result['hard']} "
        f"scenes from {result['groups']['train']} / {result['groups']['eval']} / {result['groups']['hard']} "
        f"groups; groups shared between splits: {result['shared_groups']}"
    )
    if result["hard_by"] == "pair":
        print(f"  Hard scenes whose higher-scoring agent became the ego: {result['roles_exchanged']}")
    print(f"  {'split':<8}{'GT close call':>15}{'GT collision':>14}{'AC close call':>15}{'AC collision':>14}")
    for name, cc in result["close_calls"].items():
        if cc:
            print(f"  {name:<8}{cc['gt_close_call']:>15.1%}{cc['gt_collision']:>14.1%}"
                  f"{cc['ac_close_call']:>15.1%}{cc['ac_collision']:>14.1%}")
    return 0


def cmd_data_report(args: argparse.Namespace) -> int:
    from seal.scoring.report import write_report

    for path in write_report(args.dir, args.out):
        print(f"wrote {path}")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from seal.core.dataset import Dataset
    from seal.envs.episode_video import render_episode

    out = Path(args.out)
    if out.suffix.lower() not in (".mp4", ".gif"):
        raise CliError(f"--out must end in .mp4 or .gif, got {out.name!r}")
    if args.ego or args.generator:
        return _render_protocol_episode(args)
    scenario = Dataset.open(args.dataset).get(args.scenario)
    summary = render_episode(scenario, out, fps=args.fps)
    print(json.dumps(summary, default=str))
    return 0


def _render_protocol_episode(args: argparse.Namespace) -> int:
    """``seal render --ego ... [--generator ...]``: the episode `seal eval runs` scores, played again."""
    from seal.experiments.evaluation.generators import apply_generator_options
    from seal.experiments.evaluation.replay_episode import EpisodeSpec, render

    kwargs: dict[str, dict] = {args.generator: {}} if args.generator else {}
    if args.gen_opt and not args.generator:
        raise CliError("--gen-opt needs --generator")
    apply_generator_options(kwargs, args.gen_opt)
    spec = EpisodeSpec(dataset=args.dataset, scenario_id=args.scenario, ego=args.ego or "heuristic",
                       generator=args.generator, kwargs=kwargs.get(args.generator or "", {}), k=args.k,
                       seed=args.seed, split=args.split, algo=args.algo)
    print(json.dumps(render(spec, args.out, fps=args.fps), default=str))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from seal.experiments.pipeline.demo import run_demo

    result = run_demo(Path(args.out), n_scenarios=args.n, n_rollouts=args.rollouts, seed=args.seed,
                      overwrite=args.overwrite)
    print("\n" + result["table"])
    print(result["wrote"])
    return 0


def register(tree: CommandTree) -> None:
    _register_demo(tree)
    data_sub = tree.group("data")
    _register_generate(data_sub)
    _register_dataset_tools(data_sub)
    _register_render(tree)


def _register_demo(tree: CommandTree) -> None:
    demo = tree.top.add_parser(
        "demo",
        help="the main job on the embedded default: build a small dataset, roll out, video, table",
        description="Build a small base-scenario dataset from highway-env traffic, roll a few scenarios out with "
        "the heuristic ego against the replayed adversary, write a video and a summary table into --out.",
    )
    demo.add_argument("--out", default="runs/demo", help="output folder (default: runs/demo)")
    demo.add_argument("--n", type=positive_int("--n"), default=40, help="scenarios to generate (default 40)")
    demo.add_argument("--rollouts", type=positive_int("--rollouts"), default=12, help="scenarios to roll out")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    demo.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")
    demo.set_defaults(func=cmd_demo)


def _register_generate(data_sub: argparse._SubParsersAction) -> None:
    gen = data_sub.add_parser(
        "generate",
        help="generate base scenarios from highway-env traffic",
        description="Run highway-env traffic (randomised IDM + MOBIL drivers, a share of inattentive and "
        "aggressive ones) on several layouts, log every vehicle at 10 Hz and cut 9.1 s scenarios around "
        "interacting (ego, adversary) pairs. Deterministic for a seed; an interrupted build resumes when the "
        "same command is run again.",
    )
    gen.add_argument("--out", required=True, help="dataset directory to create")
    gen.add_argument("--n", type=positive_int("--n"), required=True, help="number of scenarios")
    gen.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    gen.add_argument(
        "--layouts",
        type=layouts,
        nargs="+",
        default=[list(LAYOUTS)],
        help=f"layouts to use, space or comma separated (default: all of {', '.join(LAYOUTS)})",
    )
    gen.add_argument("--workers", type=positive_int("--workers"), default=None, help="processes (default: all cores)")
    gen.add_argument(
        "--inattentive-share",
        type=share("--inattentive-share"),
        default=0.15,
        help="share of inattentive drivers in [0, 1] (default 0.15)",
    )
    gen.add_argument(
        "--aggressive-share",
        type=share("--aggressive-share"),
        default=0.15,
        help="share of aggressive drivers in [0, 1] (default 0.15)",
    )
    gen.add_argument("--overwrite", action="store_true", help="replace an existing dataset or unfinished build")
    gen.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    gen.set_defaults(func=cmd_data_generate)


def _register_dataset_tools(data_sub: argparse._SubParsersAction) -> None:
    """``seal data info | score | split | report``."""
    info = data_sub.add_parser(
        "info",
        help="counts per layout and split, agents per scenario, track lengths",
        description="Print counts per layout and split, agents per scenario, track length statistics and how "
        "close the logged (ego, adversary) pairs come.",
    )
    info.add_argument("dir", help="dataset directory")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    info.set_defaults(func=cmd_data_info)

    score = data_sub.add_parser(
        "score",
        help="SafeShift scores (GT, FE, AS, AC) per agent and scene, stored in the dataset",
        description="Compute SafeShift individual, social, trajectory and scene scores for every scenario in all "
        "variants (ground truth, future-extrapolated, asymmetric, asymmetric-combined) and store them in DIR.",
    )
    score.add_argument("dir", help="dataset directory")
    score.add_argument("--workers", type=positive_int("--workers"), default=None, help="processes (default: all cores)")
    score.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    score.set_defaults(func=cmd_data_score)

    split = data_sub.add_parser(
        "split",
        help="Normal train / eval and Hard splits from the SafeShift scores, whole recordings per split",
        description="Hard = a seeded sample of the scenes whose interacting pair's trajectory scores are both "
        "above --hard-quantile (--hard-by pair, thesis 6.4: the higher-scoring agent becomes the ego) or whose "
        "scene score is (--hard-by scene); Normal train / eval are drawn from the rest. Windows cut from one "
        "recording or traffic run never go to two splits. Recorded in the manifest; same arguments, same splits.",
    )
    split.add_argument("dir", help="dataset directory (scored with `seal data score`)")
    split.add_argument("--hard-by", choices=("pair", "scene"), default="pair", help="Hard rule (default pair)")
    split.add_argument("--score", choices=("gt", "fe", "as", "ac"), default="ac",
                       help="SafeShift score variant the Hard rule ranks by (default ac)")
    split.add_argument("--hard-quantile", type=share("--hard-quantile"), default=0.8, help="default 0.8")
    split.add_argument("--n-train", type=non_negative_int("--n-train"), default=400,
                       help="default 400; 0 = a pool held out for evaluation only (eval and hard splits)")
    split.add_argument("--n-eval", type=positive_int("--n-eval"), default=100, help="default 100")
    split.add_argument("--n-hard", type=positive_int("--n-hard"), default=100, help="default 100")
    split.add_argument("--seed", type=int, default=42, help="default 42")
    split.add_argument("--json", action="store_true", help="print the result as JSON")
    split.set_defaults(func=cmd_data_split)

    report = data_sub.add_parser(
        "report",
        help="score distributions, feature correlations and example scenes as images",
        description="Write the score distribution plot (all variants), the feature correlation heat-map and a "
        "few top-scoring and median scenarios rendered as PNG images into --out.",
    )
    report.add_argument("dir", help="dataset directory (scored with `seal data score`)")
    report.add_argument("--out", required=True, help="output folder")
    report.set_defaults(func=cmd_data_report)


def _register_render(tree: CommandTree) -> None:
    render = tree.top.add_parser(
        "render",
        help="top-down video of a scenario roll-out",
        description="Roll a scenario out (heuristic ego, replayed adversary and traffic) and write a top-down "
        "video; the ego is green, the adversary red, other traffic blue. With --ego and / or --generator: the "
        "episode `seal eval runs` scored for that ego and setting, played again with the evaluation's seeds "
        "(the normal episode, then K passes of the generator; the last is shown).",
    )
    render.add_argument("--dataset", required=True, help="dataset directory")
    render.add_argument("--scenario", required=True, help="scenario id (see `seal data info --json` or manifest)")
    render.add_argument("--out", required=True, help="output file, .mp4 or .gif")
    render.add_argument("--fps", type=positive_int("--fps"), default=10, help="frames per second (default 10)")
    render.add_argument("--ego", default=None, help="heuristic | replay | run folder | SB3 model .zip | seal.egos "
                        "entry point (default heuristic)")
    render.add_argument("--algo", default=None, help="SB3 algorithm of an --ego model file that does not record it")
    render.add_argument("--generator", default=None, help="adversary generator of the setting (default: the log)")
    render.add_argument("--gen-opt", action="append", default=[], metavar="NAME.KEY=VALUE",
                        help="generator option, as in seal eval runs (repeatable)")
    render.add_argument("--k", type=positive_int("--k"), default=5, help="perturbation passes (default 5)")
    render.add_argument("--seed", type=int, default=0, help="the evaluation's seed (default 0)")
    render.add_argument("--split", default=None,
                        help="split the scenario was evaluated in (default: the split holding it, eval first)")
    add_plugin_option(render)
    render.set_defaults(func=cmd_render)
