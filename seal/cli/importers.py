"""``seal data import commonroad|scenarionet`` and ``seal data replay-check``."""

from __future__ import annotations

import argparse
import json

from seal.cli.args import positive_int
from seal.cli.tree import CommandTree

_DESCRIPTIONS = {  # format: (help, description, default scenarios per file = seal.core.importers.FORMATS)
    "commonroad": (
        "import CommonRoad XML scenarios (2018b, 2020a)",
        "Read CommonRoad XML files (versions 2018b and 2020a): the road from the lanelets (centre lines and "
        "widths from the left / right bounds, solid / dashed lines from the markings, on-ramps included) and the "
        "dynamic obstacles' rectangle shapes and state trajectories (resampled to 10 Hz if needed); cut 9.1 s "
        "windows around interacting (ego, adversary) pairs, several per file. Directories are searched for "
        "*.xml; a bad file is reported and skipped.",
        8,
    ),
    "scenarionet": (
        "import ScenarioNet scenario pickles (Waymo, nuScenes, nuPlan, Argoverse 2)",
        "Read ScenarioNet scenario pickles through a restricted unpickler (numpy arrays and plain containers "
        "only; anything else is refused): tracks with state arrays and valid masks, lane polylines from the map "
        "features. The ego is the SDC, the adversary the other object of interest or the most interacting "
        "vehicle. Directories are searched for *.pkl; a bad file is reported and skipped.",
        1,
    ),
}


def cmd_import(args: argparse.Namespace) -> int:
    from seal.core.importers import import_files

    ds, report = import_files(
        args.inputs,
        args.out,
        args.import_format,
        max_per_file=args.max_per_file,
        min_future_steps=args.min_future_steps,
        overwrite=args.overwrite,
        progress=not args.no_progress,
    )
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(
        f"imported {report['scenarios']} scenarios from {report['imported_files']} of {report['files']} files "
        f"into {ds.root} ({report['seconds']:.1f} s)"
    )
    if report["skipped"]:
        print(f"skipped {report['skipped_files']} file(s):")
        for row in report["skipped"]:
            print(f"  {row['reason']}")
    return 0


def cmd_replay_check(args: argparse.Namespace) -> int:
    from seal.experiments.evaluation.replay_check import run

    return run(args.dir, args.out, args.limit, progress=not args.no_progress, ego=args.ego)


def register(tree: CommandTree) -> None:
    data_sub = tree.group("data")
    imp = data_sub.add_parser(
        "import",
        help="import recorded scenarios (CommonRoad XML, ScenarioNet pickles) as a dataset",
        description="Import recorded driving scenarios into a seal dataset: the road from the recorded map, the "
        "agents' tracks at 10 Hz, and 9.1 s windows around interacting (ego, adversary) pairs. The result is an "
        "ordinary dataset (score, split, evaluate it like a generated one). The import is atomic: it is built in a "
        "hidden staging folder next to --out and renamed when complete, so a failed import leaves nothing behind; "
        "an interrupted one resumes, reading again the files that changed. --json prints the report: files read "
        "and skipped (with reasons), scenarios, and what was repaired or dropped and why.",
    )
    formats = imp.add_subparsers(dest="import_format", metavar="FORMAT", required=True)
    for fmt, (help_text, description, per_file) in _DESCRIPTIONS.items():
        p = formats.add_parser(fmt, help=help_text, description=description)
        p.add_argument("inputs", nargs="+", metavar="FILE_OR_DIR", help="files or directories to import")
        p.add_argument("--out", required=True, help="dataset directory to create")
        p.add_argument(
            "--max-per-file", type=positive_int("--max-per-file"), default=None,
            help=f"most scenarios per file (default {per_file})",
        )
        p.add_argument(
            "--min-future-steps", type=positive_int("--min-future-steps"), default=20,
            help="logged future steps (0.1 s) the ego and the adversary need in a window (default 20)",
        )
        p.add_argument("--overwrite", action="store_true", help="replace an existing dataset or unfinished import")
        p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
        p.add_argument("--json", action="store_true", help="print the full import report as JSON")
        p.set_defaults(func=cmd_import)

    check = data_sub.add_parser(
        "replay-check",
        help="replay every scenario's logged ego in ScenarioEnv: arrival rate and why others fail",
        description="Drive each scenario's logged ego through the bicycle model (actions recovered from its log) "
        "in ScenarioEnv with every other agent replaying its log; print the success rate and, for each failure, "
        "whether it left the road (and which test fired) or crashed (and whether the logged boxes overlap too).",
    )
    check.add_argument("dir", help="dataset directory")
    check.add_argument("--out", default=None, help="write the full result (one row per scenario) as JSON")
    check.add_argument("--limit", type=positive_int("--limit"), default=None, help="only the first N scenarios")
    check.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    check.add_argument(
        "--ego", choices=("logged", "heuristic"), default="logged",
        help="who drives the ego: its logged track (default) or the rule-based heuristic driver, whose failures "
        "get the same explanations",
    )
    check.set_defaults(func=cmd_replay_check)
