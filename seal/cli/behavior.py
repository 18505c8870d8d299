"""``seal fit behavior``: RCG's behaviour embedding (thesis 7.3) and its Table 7.5 analysis."""

from __future__ import annotations

import argparse

from seal.cli.args import add_fit_job_options, positive_int, set_torch_threads
from seal.cli.tree import CommandTree


def cmd_fit_behavior(args: argparse.Namespace) -> int:
    import json

    from seal.experiments.fitting.behavior import fit_behavior, format_summary, resolve_config

    config = resolve_config(
        preset=args.preset, config_file=args.config, sets=args.set, split=args.split, eval_split=args.eval_split,
        limit=args.limit, eval_limit=args.eval_limit, max_samples=args.max_samples,
        crash_datasets=args.crash_dataset or None,
        seeds=None if args.seed is None else [args.seed], threads=args.threads,
    )
    set_torch_threads(config.threads)
    report = fit_behavior(args.dataset, args.out, config, progress=not args.no_progress)
    print(json.dumps(report, indent=2, default=str) if args.json else format_summary(report))
    return 0


def register(tree: CommandTree) -> None:
    p = tree.group("fit").add_parser(
        "behavior",
        help="train RCG's behaviour embedding (full-trajectory encoder, ProtoNCE, LoRA on the crash set) for "
        "cat-rcg / seal-rcg",
        description="Label every agent of the training split safe / neutral / unsafe from its SafeShift scores "
        "(diff = GT - FE, delta chosen for even classes, thesis eq. 7.1); build the crash set (logged pairs that "
        "collide or come within crash.near_miss_m, labelled by cause and reaction, plus --crash-dataset datasets); "
        "per seed pre-train the encoder with L_recon + lambda ProtoNCE and with L_recon alone, fine-tune a LoRA "
        "adapter of each on the crash set; cache every variant's unsafe embeddings; report Table 7.5 (per-class "
        "k-means silhouette / Davies-Bouldin over 3-6 clusters, linear-probe accuracy on the held-out split). "
        "Writes behavior.pt (+ .json), variants/, report.json, report.md, train_log.csv, config.yaml to --out.",
    )
    add_fit_job_options(p, "behavior", "seal.experiments.fitting.behavior.BehaviorFitConfig",
                        "train.epochs=5 or model.latent_dim=128", "report")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--split", default=None, help="split of the training behaviours and crash set "
                   "(default all-but-eval)")
    p.add_argument("--eval-split", default=None, help="held-out split of the analysis (default eval)")
    p.add_argument("--limit", type=positive_int("--limit"), default=None, help="use the first N training scenarios")
    p.add_argument("--eval-limit", type=positive_int("--eval-limit"), default=None,
                   help="use the first N held-out scenarios")
    p.add_argument("--max-samples", type=positive_int("--max-samples"), default=None,
                   help="at most N training behaviours (a seeded draw)")
    p.add_argument("--crash-dataset", action="append", default=[], metavar="DIR",
                   help="another dataset whose near misses join the crash set (repeatable), e.g. imported NGSIM")
    p.add_argument("--threads", type=positive_int("--threads"), default=None, help="torch threads (default 1)")
    p.set_defaults(func=cmd_fit_behavior)
