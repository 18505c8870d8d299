"""Videos of failures for the report: for every ego and setting, up to N episodes of each failure kind (crash,
off-road, timeout), played again with the evaluation's seeds, generator options and K
(`seal.experiments.evaluation.replay_episode`).

Egos that exist only in the evaluating process (a Python policy passed to ``evaluate_policy``) cannot be played
again from the store and are skipped with a log line, as are settings the store has no record of.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.core.errors import SealError
from seal.experiments.report.failures import FAILURE_KINDS

logger = logging.getLogger(__name__)


def pick_failures(failures: Sequence[Mapping[str, Any]], per_kind: int) -> list[Mapping[str, Any]]:
    """The first ``per_kind`` failures of each kind for every (ego run, setting), in `failure_list` order."""
    taken: dict[tuple[str, str, str], int] = {}
    out = []
    for f in failures:
        key = (str(f["run"]), str(f["setting"]), str(f["outcome"]))
        if f["outcome"] in FAILURE_KINDS and taken.get(key, 0) < per_kind:
            taken[key] = taken.get(key, 0) + 1
            out.append(f)
    return out


def render_failure_videos(
    failures: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]],
    settings_info: Sequence[Mapping[str, Any]], out: Path, per_kind: int = 1, fmt: str = "mp4",
    progress: bool = True,
) -> dict[tuple[str, str, str], str]:
    """Write the videos of `pick_failures` into ``out``; returns ``{(run, setting label, scenario_id): path}``
    (path relative to ``out.parent``, for links from report.md)."""
    from tqdm import tqdm

    from seal.experiments.evaluation.replay_episode import EpisodeSpec, render

    if fmt not in ("mp4", "gif"):
        raise ValueError(f"--video-format must be mp4 or gif, got {fmt!r}")
    ego_of = {str(r["run"]): (r.get("path") or r["run"], (r.get("config") or {}).get("algo")) for r in runs}
    setting_of = {(s["dataset"], s["setting"]): s for s in settings_info}
    videos: dict[tuple[str, str, str], str] = {}
    chosen = pick_failures(failures, per_kind)
    for f in tqdm(chosen, desc="failure videos", unit="video", disable=not progress or not chosen):
        setting = setting_of.get((f["dataset"], f["setting_name"]))
        spec_ego, algo = ego_of.get(str(f["run"]), (f["run"], None))
        if setting is None:
            logger.info(f"no video of {f['scenario_id']} ({f['setting']}): the store has no record of the setting")
            continue
        spec = EpisodeSpec.of_setting({**setting, "dataset": f["dataset"]}, f["scenario_id"], spec_ego,
                                      algo if algo and algo != "reskill" else None)
        # pipeline labels tell egos apart (cat@step_2000, dir/model); the run's name tells seeds apart
        ego = f"{_slug(str(f['pipeline']))}_{_slug(Path(str(f['run'])).name)}"
        name = f"{f['outcome']}_{_slug(f['setting'])}_{ego}_{f['scenario_id']}.{fmt}"
        try:
            render(spec, out / name)
        except (SealError, ValueError, OSError) as exc:
            logger.info(f"no video of {f['scenario_id']} for {f['run']} ({f['setting']}): {exc}")
            continue
        videos[(str(f["run"]), str(f["setting"]), str(f["scenario_id"]))] = f"{out.name}/{name}"
    return videos


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-." else "-" for c in text).strip("-") or "x"
