"""``seal compare``: thesis-style tables (Markdown + CSV), plots and videos from the results store."""

from __future__ import annotations

import argparse

from seal.cli.args import CliError, add_plugin_option, positive_int
from seal.cli.tree import CommandTree

# The defaults of seal.experiments.report.stats.N_BOOT / N_BOOT_POI, repeated so `seal compare --help` stays fast
# (the report modules import rliable); tests/experiments/test_report_stats.py checks they agree.
N_BOOT_DEFAULT = 2000
N_BOOT_POI_DEFAULT = 1000


def _names(text: str | None) -> list[str] | None:
    return [t.strip() for t in text.split(",") if t.strip()] if text else None


def cmd_compare(args: argparse.Namespace) -> int:
    from pathlib import Path

    from seal.experiments.report.compare import ego_markdown, generator_markdown
    from seal.experiments.report.write import write_report

    if not Path(args.store).is_file():
        raise CliError(f"--store {args.store}: no such results store (fill one with `seal eval runs`)")
    if args.videos > 0 or args.failure_videos > 0:  # re-simulated: torch threads as the evaluation workers had
        from seal.adversaries.candidate_sources import PRIOR_THREADS
        from seal.cli.args import set_torch_threads

        set_torch_threads(PRIOR_THREADS)
    if args.failure_videos < 0 or args.videos < 0:
        raise CliError("--videos and --failure-videos must be >= 0")
    result = write_report(
        args.store, args.out, pipelines=_names(args.pipeline), settings=_names(args.setting),
        plots=not args.no_plots, videos=args.videos, video_format=args.video_format, progress=not args.no_progress,
        datasets=_names(args.dataset), failure_videos=args.failure_videos, n_boot=args.reps,
        n_boot_poi=args.poi_reps,
    )
    if args.json:
        import json

        from seal.experiments.evaluation.generators import jsonable

        keys = ("table_6_1", "table_6_2", "ego_ci", "improvement", "improvement_per_setting", "paired",
                "generator_ci", "agreement", "success_differences", "outcomes", "by_layout", "by_source", "failures",
                "figures", "videos", "failure_videos", "episodes")
        print(json.dumps(jsonable({k: result[k] for k in keys}), default=str))
        return 0
    print(ego_markdown(result["table_6_1"]))
    if result["table_6_2"]:
        print(generator_markdown(result["table_6_2"]))
    print(f"wrote {args.out}/report.md, table_6_1.csv, table_6_2.csv, rates_per_run.csv, outcomes*.csv, failures.csv"
          + (f", {len(result['figures'])} figures" if result["figures"] else "")
          + (f", {len(result['videos'])} videos" if result["videos"] else "")
          + (f", {len(result['failure_videos'])} failure videos" if result["failure_videos"] else ""))
    return 0


def register(tree: CommandTree) -> None:
    p = tree.top.add_parser(
        "compare",
        help="report from a results store: Table 6.1 / 6.2 as Markdown + CSV, plots, videos",
        description="Read the evaluation episodes of a results store (seal eval runs / seal run) and write into "
        "--out: report.md (first page: which pipeline wins where, by how much, how sure; the thesis's findings "
        "checked); ego_ci.csv (per pipeline x setting, rliable: mean and IQM of the seeds' rates with 95 % "
        "crossed-bootstrap intervals over seeds and scenarios); improvement.csv (probability of improvement of "
        "every pipeline over every other, with its interval and a permutation test's p); gaps.csv (the first page's "
        "margins, paired on the same scenarios); success_differences.csv "
        "(each pipeline's success minus No-Adv's per setting and over all settings, Welch's interval over the seeds; "
        "success_differences*.png); agreement.csv (do egos of one pipeline fail the same scenarios?); paired.csv / "
        "per_scenario.csv (which scenarios one pipeline solves and another does not); generator_ci.csv (realism and "
        "collision speed with intervals); generator_differences.csv (every generator minus every other, paired on the "
        "same scenarios, with the collision speed also on matched contacts: same ego, same scenario); "
        "ci_success_mean.png / ci_success_iqm.png; table_6_1.csv (per pipeline x "
        "setting: median, q25, q75, IQR over seeds of success / "
        "crash / out-of-road rates); table_6_2.csv (per generator: ego success averaged over egos, realism "
        "Wasserstein distances, collision speed, head-on rates, generation time; with egos of several algorithms, "
        "over all egos and against each algorithm's egos apart, column ego_group); rates_per_run.csv; "
        "bars_<metric>.png (median with IQR per setting); training_curves.png (from each run's progress.csv); "
        "and with --videos N, N videos per generator against one ego; outcomes.csv / outcomes_by_layout.csv / "
        "outcomes_by_source.csv (success, crash, out-of-road, timeout shares with n and route completion), "
        "failures.csv (every failed scenario per ego and setting with the reason; failures.md lists them per ego "
        "and setting, report.md sums them per pipeline), with --failure-videos N videos of N failures of each kind "
        "per ego and setting, eval_curves.png (the runs' periodic evaluations) and convergence.csv (per pipeline: "
        "were its egos still improving when training stopped? also on the first page). "
        "Datasets are kept apart (settings read normal@DATASET when the store holds several) and egos without a "
        "pipeline are never grouped as seeds of one; egos of several algorithms read '<pipeline> (<algo>)' and are "
        "compared only within their algorithm.",
    )
    p.add_argument("--store", default="results.sqlite", help="SQLite results store (default results.sqlite)")
    p.add_argument("--out", required=True, help="report folder")
    p.add_argument("--pipeline", default=None, help="only these pipelines (comma-separated, e.g. noadv,cat,replay)")
    p.add_argument("--setting", default=None, help="only these settings (comma-separated, e.g. normal,hard,cat)")
    p.add_argument("--dataset", default=None,
                   help="only episodes on these datasets (comma-separated paths or folder names)")
    p.add_argument("--failure-videos", type=int, default=0,
                   help="videos of up to N failures of each kind (crash, out-of-road, timeout) per ego and setting "
                   "(default 0; re-simulates)")
    p.add_argument("--json", action="store_true", help="print the tables and failures as JSON")
    p.add_argument("--no-plots", action="store_true", help="tables only")
    p.add_argument("--videos", type=int, default=0, help="videos per generator setting (default 0; re-simulates)")
    p.add_argument("--video-format", choices=("mp4", "gif"), default="mp4", help="video format (default mp4)")
    p.add_argument("--reps", type=positive_int("--reps"), default=N_BOOT_DEFAULT,
                   help=f"bootstrap resamples of the success / crash intervals (default {N_BOOT_DEFAULT})")
    p.add_argument("--poi-reps", type=positive_int("--poi-reps"), default=N_BOOT_POI_DEFAULT,
                   help=f"bootstrap resamples of the probabilities of improvement (default {N_BOOT_POI_DEFAULT}; "
                   "~20 us each per pipeline pair)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_plugin_option(p)
    p.set_defaults(func=cmd_compare)
