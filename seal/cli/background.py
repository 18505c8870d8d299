"""``seal fit background`` / ``seal eval background`` / ``seal bench background``: RAPID-style reactive background
traffic (paper 004) beside replay and IDM (issue 22)."""

from __future__ import annotations

import argparse

from seal.cli.args import CliError, add_fit_job_options, positive_int, print_result, set_torch_threads
from seal.cli.tree import CommandTree


def _guidance(items: list[str]) -> dict[str, float]:
    """``--guidance KEY=VALUE`` options as a dict (the loader names unknown keys)."""
    out: dict[str, float] = {}
    for item in items:
        key, sep, value = item.partition("=")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise CliError(f"--guidance {item!r}: expected KEY=NUMBER, e.g. w_social=0.8") from None
        if not sep:
            raise CliError(f"--guidance {item!r}: expected KEY=NUMBER, e.g. w_social=0.8")
    return out


def cmd_fit_background(args: argparse.Namespace) -> int:
    import json

    from seal.experiments.fitting.background import fit_background, format_summary, resolve_config

    config = resolve_config(preset=args.preset, config_file=args.config, sets=args.set, seed=args.seed,
                            limit=args.limit)
    set_torch_threads(config.threads)
    report = fit_background(args.dataset, args.out, config, progress=not args.no_progress)
    print(json.dumps(report, indent=2, default=str) if args.json else format_summary(report))
    return 0


def cmd_eval_background(args: argparse.Namespace) -> int:
    import json

    from seal.experiments.evaluation.background_job import run_background_eval

    set_torch_threads(1)
    report = run_background_eval(
        args.dataset, args.model, args.out, split=args.split, limit=args.limit, parts=args.parts.split(","),
        egos=tuple(args.ego) or ("heuristic",), closed_dataset=args.closed_dataset, closed_limit=args.closed_limit,
        seed=args.seed, guidance=_guidance(args.guidance), ddim_steps=args.ddim_steps,
        progress=not args.no_progress)
    print(json.dumps(report, indent=2, default=str) if args.json else json.dumps(
        {k: v for k, v in report.items()
         if k in ("open_loop", "intent", "intent_idm_reference", "rear_end_rate_change_vs_replay")},
        indent=1, default=str))
    return 0


def cmd_bench_background(args: argparse.Namespace) -> int:
    from seal.experiments.bench.background import run_background_bench

    counts = tuple(int(c) for c in args.counts.split(","))
    result = run_background_bench(args.dataset, args.model, counts, steps=args.steps,
                                  guidance=_guidance(args.guidance), ddim_steps=args.ddim_steps)
    print_result(result, args.json)
    return 0


def _model_options(p: argparse.ArgumentParser, required: bool) -> None:
    p.add_argument("--model", required=required, default=None,
                   help="RAPID model file (seal fit background OUT/model.pt)")
    p.add_argument("--guidance", action="append", default=[], metavar="KEY=VALUE",
                   help="physics guidance option of seal.models.rapid.Guidance, repeatable (e.g. w_social=0.8; "
                   "all w_*=0: unguided)")
    p.add_argument("--ddim-steps", type=positive_int("--ddim-steps"), default=5, help="DDIM steps per env step")


def register(tree: CommandTree) -> None:
    fit = tree.group("fit").add_parser(
        "background", help="train the RAPID background model (next-step acceleration diffusion, paper 004)",
        description="Train the RAPID-style background model on the logged tracks of a dataset's training split: "
        "agent-centric inputs with Fourier position, cached map latents, intent inputs (desired speed, destination), "
        "a small x0 denoiser. Writes OUT/model.pt and OUT/report.json; use it with ScenarioEnv background: rapid.")
    add_fit_job_options(fit, "background", "seal.experiments.fitting.background.BackgroundFitConfig",
                        "epochs=2 or dim=32", "report")
    fit.add_argument("out", help="output folder (model.pt, report.json)")
    fit.add_argument("--limit", type=positive_int("--limit"), default=None, help="first N training scenarios")
    fit.set_defaults(func=cmd_fit_background)

    ev = tree.group("eval").add_parser(
        "background", help="ADE / FDE, collisions, intent control and rear-end hits of each background kind",
        description="On held-out scenarios: open-loop next-step and 8 s ADE / FDE of constant velocity, IDM and "
        "RAPID (guided and unguided) against the logs and their background collision rates; RAPID's intent control "
        "(speed and heading R^2); closed loop: how often background traffic hits the ego from behind with replay, "
        "IDM and RAPID background, for each ego. Writes OUT/background_eval.json and .png.")
    ev.add_argument("dataset", help="dataset with a held-out split")
    _model_options(ev, required=False)
    ev.add_argument("--out", default=None, help="folder for background_eval.json / .png")
    ev.add_argument("--split", default="eval", help="held-out split (default eval)")
    ev.add_argument("--limit", type=positive_int("--limit"), default=None, help="first N held-out scenarios")
    ev.add_argument("--parts", default="open,intent,closed", help="comma list of open, intent, closed")
    ev.add_argument("--ego", action="append", default=[],
                    help="closed-loop ego: heuristic or a seal train run folder; repeatable (default heuristic)")
    ev.add_argument("--closed-dataset", default=None, help="dataset of the closed loop (default DATASET)")
    ev.add_argument("--closed-limit", type=positive_int("--closed-limit"), default=None,
                    help="first N scenarios of the closed loop")
    ev.add_argument("--seed", type=int, default=0, help="seed (episodes as seal eval runs)")
    ev.add_argument("--no-progress", action="store_true", help="no progress bars")
    ev.add_argument("--json", action="store_true", help="print the whole report as JSON")
    ev.set_defaults(func=cmd_eval_background)

    b = tree.group("bench").add_parser(
        "background", help="ms per env step of all background agents (RAPID and IDM) at 5 / 20 / 60 / 120 agents",
        description="Time the background controller's step on one CPU thread as the number of background agents "
        "grows (a dataset scenario's agents tiled); budget 30 ms at 60 agents, 120-agent time <= 1.5 x 5-agent.")
    b.add_argument("--dataset", default=None, help="dataset to take the scene from (default: in-memory traffic)")
    _model_options(b, required=True)
    b.add_argument("--counts", default="5,20,60,120", help="comma list of background agent counts")
    b.add_argument("--steps", type=positive_int("--steps"), default=40, help="timed steps per count")
    b.add_argument("--json", action="store_true", help="print the result as JSON")
    b.set_defaults(func=cmd_bench_background)
