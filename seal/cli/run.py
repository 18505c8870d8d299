"""``seal run PRESET.yaml``: data -> scores -> splits -> model fits -> train pipelines x seeds -> eval -> report."""

from __future__ import annotations

import argparse

from seal.cli.args import CliError, add_plugin_option, add_set_option, positive_int
from seal.cli.tree import CommandTree


def cmd_run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from seal.experiments.backends import make_backend
    from seal.experiments.pipeline.run import load_run_config, run_pipeline

    try:
        config = load_run_config(args.config, args.set)
    except (OSError, ValueError) as exc:
        raise CliError(str(exc)) from None
    out = args.out or str(Path("runs") / Path(args.config).stem)
    if args.status:
        from seal.experiments.pipeline.status import format_status, run_status

        status = run_status(args.config, out, args.set)
        print(json.dumps(status, indent=2) if args.json else format_status(status))
        return 0
    if args.check:
        from seal.experiments.pipeline.run import check_run

        try:
            plan = check_run(args.config, out, args.set)
        except (OSError, ValueError) as exc:
            raise CliError(f"{args.config}: {exc}") from None
        print(json.dumps(plan, indent=2) if args.json else
              f"{args.config}: plan ok: {len(plan['runs'])} training runs, fits {', '.join(plan['fits']) or 'none'}, "
              f"evaluation on {', '.join(plan['eval_settings'])} (K = {plan['eval_k']})"
              + (f", also on the held-out pools {', '.join(plan['eval_heldout'])}" if plan.get("eval_heldout") else "")
              + (f"; {plan['reuse']}" if plan.get("reuse") else ""))
        return 0
    bcfg = config.get("backend") or {}
    name = args.backend or bcfg.get("name", "local")
    workers = args.workers if args.workers is not None else bcfg.get("workers")
    try:
        backend = make_backend(name, workers, address=args.address or bcfg.get("address"))
    except RuntimeError as exc:
        raise CliError(str(exc)) from None
    try:
        summary = run_pipeline(args.config, out, backend=backend, progress=not args.no_progress, sets=args.set)
    except RuntimeError as exc:
        print(f"seal run: {exc}")
        return 1
    print(json.dumps(summary, indent=2))
    return 0


def register(tree: CommandTree) -> None:
    p = tree.top.add_parser(
        "run",
        help="the whole experiment of a preset: data, scores, splits, fits, training x seeds, eval, report",
        description="Run every step of an experiment preset (experiments/configs/quick|standard|paper|decisive.yaml): "
        "generate, score and split the data; fit the models the generators need (prior, GOOSE, skills, "
        "objective); train one ego per pipeline x seed; evaluate every ego plus the Replay ego into "
        "OUT/results.sqlite; write OUT/report. Finished steps are skipped on re-run (markers in OUT/steps, run "
        "folders with done.json, evaluations already in the store), also after the folder was moved or copied "
        "(its store and run configs are pointed at the new path first; OUT/steps/location.json). Train and eval "
        "jobs run on the local "
        "machine in processes (--backend local) or as Ray tasks on a running cluster (--backend ray; start one "
        "with `ray start --head`; address from --address, the preset's backend.address, RAY_ADDRESS or auto). "
        "--set reuse=OTHER_OUT takes the data and the fitted models of another run folder wherever they were made "
        "with this preset's options (e.g. a second comparison with other ego settings on the same models); the "
        "rest is made here. eval.heldout in the preset plays every setting but real: also on other pools' eval / "
        "hard splits: dataset folders, or {name, generate, score, split} entries that the run builds into "
        "OUT/heldout/<name> right after its own data (the decisive preset builds a 600 + 600 scenario pool of "
        "other traffic runs, what a +/-5 point success interval needs).",
    )
    p.add_argument("config", help="preset YAML, e.g. experiments/configs/quick.yaml")
    p.add_argument("--out", default=None, help="output folder (default runs/<preset name>)")
    p.add_argument("--backend", choices=("local", "ray"), default=None,
                   help="where train / eval jobs run (default: the preset's backend.name, else local)")
    p.add_argument("--workers", type=positive_int("--workers"), default=None,
                   help="local worker processes (default: the preset's backend.workers, else the CPU count)")
    p.add_argument("--address", default=None, help="Ray cluster address (default RAY_ADDRESS, else auto)")
    add_set_option(p, "eval.limit=5 or seeds=[0]")
    p.add_argument("--check", action="store_true",
                   help="check the whole plan (every step's options, names, paths) and print what it would run; "
                   "writes nothing")
    p.add_argument("--status", action="store_true",
                   help="where a run in --out stands (for a run carried across sessions): each data / fit step done "
                   "(with its time), changed, started or pending; training runs done, in progress (steps of the newest "
                   "checkpoint) or not started, with the finished runs' mean time and the time left at that pace; "
                   "evaluation rows stored of those a complete evaluation writes; the report; writes nothing")
    p.add_argument("--json", action="store_true", help="with --check or --status: print it as JSON")
    add_plugin_option(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_run)
