"""``seal fit probes`` and ``seal eval steering``: latent probes and steering vectors of a trajectory prior."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from seal.cli.args import CliError, add_set_option, positive_int
from seal.cli.tree import CommandTree


def _config(cls: type, path: str | None, values: dict[str, Any], sets: list[str]) -> Any:
    from seal.core.config import load_config

    if path is not None and not Path(path).is_file():
        raise CliError(f"--config: file {path} not found")
    return load_config(cls, file=path, values=values, overrides=sets)


def _load(prior_path: str, dataset: str, split: str, limit: int | None) -> tuple[Any, list[Any]]:
    import torch

    from seal.core.dataset import load_split
    from seal.models.prior.prior import TrajectoryPrior

    torch.set_num_threads(1)  # entry point: batch inference of a small transformer is fastest on one thread
    prior = TrajectoryPrior.load(prior_path)
    try:
        scenarios = load_split(dataset, split, limit)
    except ValueError as exc:
        raise CliError(f"--split {split!r}: {exc}") from None
    return prior, scenarios


def cmd_fit_probes(args: argparse.Namespace) -> int:
    from seal.experiments.steering.fit import ProbeFitConfig, fit_probes

    cfg = _config(ProbeFitConfig, args.config, {"split": args.split, "limit": args.limit,
                                                "max_targets": args.max_targets, "seed": args.seed}, args.set)
    prior, scenarios = _load(args.prior, args.dataset, cfg.split, cfg.limit)
    info = {"prior": str(Path(args.prior).resolve()), "dataset": str(Path(args.dataset).resolve()),
            "split": cfg.split, "scenarios": len(scenarios)}
    report = fit_probes(prior, scenarios, args.out, cfg, info=info, progress=not args.no_progress)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"probes on {report['data']['targets']} targets of {report['data']['scenes']} scenes "
          f"({report['data']['held_out_targets']} held out by scene)")
    print(f"{'site':<8}{'R2 activity':>13}{'R2 proximity':>14}" + "".join(
        f"{'acc ' + n:>20}" for n in ("speed", "acceleration", "direction", "lane_change")))
    for site, p in report["probes"].items():
        accs = "".join(f"{p[f'acc_{n}'].get('test', float('nan')):>11.3f} ({p[f'acc_{n}'].get('majority', 0):.2f})"
                       for n in ("speed", "acceleration", "direction", "lane_change"))
        print(f"{site:<8}{p['r2_activity']['test']:>13.3f}{p['r2_proximity']['test']:>14.3f}{accs}")
    print(f"(accuracy (majority-class accuracy)); best sites: {report['best_site']}")
    print(f"wrote {args.out}/steering.pt ({len(report['vectors'])} vectors), report.json, config.yaml")
    return 0


def cmd_eval_steering(args: argparse.Namespace) -> int:
    from seal.experiments.steering.evaluate import SteeringEvalConfig, evaluate_steering, write_report
    from seal.models.steering.bundle import SteeringBundle

    values = {"split": args.split, "limit": args.limit, "max_targets": args.max_targets, "seed": args.seed,
              "shift_dataset": args.shift_dataset, "shift_split": args.shift_split}
    cfg = _config(SteeringEvalConfig, args.config, values, args.set)
    if args.no_road:
        from dataclasses import replace

        cfg = replace(cfg, check_road=False)
    bundle = SteeringBundle.load(args.steering)
    prior, scenarios = _load(args.prior, args.dataset, cfg.split, cfg.limit)
    shifted = None
    if cfg.shift_dataset is not None:
        from seal.core.dataset import load_split

        shifted = load_split(cfg.shift_dataset, cfg.shift_split, what="domain-shift")
    report = evaluate_steering(prior, bundle, scenarios, cfg, shifted, progress=not args.no_progress)
    report["prior"], report["steering"] = str(args.prior), str(args.steering)
    write_report(report, args.out)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        _print_summary(report)
        print(f"wrote {args.out}/report.json and plots")
    return 0


def _print_summary(report: dict[str, Any]) -> None:
    print(f"{report['targets']} targets of {report['scenes']} scenes")
    for name, sec in report["risk"].items():
        m = sec["margin"]
        print(f"{name:<28} alpha {sec['alpha_report']}: {sec['feature']} margin over random {m['mean']:+.4f} "
              f"[{m['ci_low']:+.4f}, {m['ci_high']:+.4f}], drivable {sec['plausible_structured']:.3f} "
              f"(random {sec['plausible_random']:.3f}, unsteered {sec.get('plausible_unsteered') or float('nan'):.3f}"
              f"; decoder before road projection {sec['plausible_raw_structured']:.3f} / "
              f"{sec['plausible_raw_random']:.3f})")
    for name, sec in report["speed"].items():
        lin = sec["linearity"]
        print(f"{name:<28} Pearson {lin['pearson']:.3f}, R2 fit {lin['r2_fit']:.3f}, R2 identity "
              f"{lin['r2_identity']:.3f}, S-idx {lin['straightness']:.3f}, slope {lin['slope']:.3f}")
    for label, sec in (("slowed", report["domain_shift"]["synthetic"]), ("dataset", report["domain_shift"].get(
            "dataset"))):
        for row in (sec or {}).get("rows", []):
            print(f"{label:<8}{str(row['vector']):<28}tau {row['tau_pct']:>7.1f}%  minADE@6 {row['min_ade']:.3f}  "
                  f"minFDE@6 {row['min_fde']:.3f}  miss {row['miss_rate']:.3f}")


def register(tree: CommandTree) -> None:
    fit = tree.group("fit").add_parser(
        "probes",
        help="linear probes, risk / control vectors and SAEs on a trajectory prior's latents (papers 000 / 002)",
        description="Collect the prior's hidden states (input embedding, after each encoder layer, output) of every "
        "agent with a full 8 s future, label their logged futures (activity risk, proximity risk to the ego, "
        "speed / acceleration / direction / lane-change classes), fit ridge and softmax probes with held-out "
        "scenes, PCA-whitened risk vectors, PCA control vectors and SAE-refined ones. Writes DIR/steering.pt, "
        "DIR/report.json, DIR/config.yaml.",
    )
    fit.add_argument("prior", help="trajectory prior file (seal fit prior)")
    fit.add_argument("dataset", help="dataset directory")
    fit.add_argument("--out", required=True, help="output folder")
    fit.add_argument("--split", default=None, help="split to read latents from (default: train)")
    fit.add_argument("--limit", type=positive_int("--limit"), default=None, help="first N scenarios only")
    fit.add_argument("--max-targets", type=positive_int("--max-targets"), default=None,
                     help="draw at most N targets (default 6000)")
    fit.add_argument("--seed", type=int, default=None, help="seed (default 0)")
    fit.add_argument("--config", default=None, help="YAML with ProbeFitConfig keys")
    add_set_option(fit, "sae_widths=[64,128] or risk.proximity_m=5")
    fit.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    fit.add_argument("--json", action="store_true", help="print the report as JSON")
    fit.set_defaults(func=cmd_fit_probes)

    ev = tree.group("eval").add_parser(
        "steering",
        help="risk vs alpha (structured vs random), plausibility, speed-control linearity, domain shift",
        description="Steer the prior's latents with the vectors of `seal fit probes` on a split's targets: risk of "
        "the predictions against alpha for each risk vector and for a random direction of the same norm (margin "
        "with a bootstrap CI), share of drivable candidates, linearity of the relative speed change against tau "
        "for the speed / acceleration control vectors (plain PCA and SAE), and minADE@6 / miss rate on futures "
        "slowed to half speed (and on --shift-dataset) with and without the vector. Writes DIR/report.json and "
        "plots.",
    )
    ev.add_argument("prior", help="trajectory prior file")
    ev.add_argument("steering", help="folder or file written by seal fit probes")
    ev.add_argument("dataset", help="dataset directory")
    ev.add_argument("--out", required=True, help="output folder")
    ev.add_argument("--split", default=None, help="split of the targets (default: eval)")
    ev.add_argument("--limit", type=positive_int("--limit"), default=None, help="first N scenarios only")
    ev.add_argument("--max-targets", type=positive_int("--max-targets"), default=None,
                    help="at most N targets (default 300)")
    ev.add_argument("--shift-dataset", default=None, help="a second dataset for the domain-shift table")
    ev.add_argument("--shift-split", default=None, help="its split (default: every scenario)")
    ev.add_argument("--seed", type=int, default=None, help="seed (default 0)")
    ev.add_argument("--no-road", action="store_true", help="skip the drivability check (faster)")
    ev.add_argument("--config", default=None, help="YAML with SteeringEvalConfig keys")
    add_set_option(ev, "alphas=[0,1.5] or risk_vectors=[risk_proximity@layer1]")
    ev.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    ev.add_argument("--json", action="store_true", help="print the report as JSON")
    ev.set_defaults(func=cmd_eval_steering)
