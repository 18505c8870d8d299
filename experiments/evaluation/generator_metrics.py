"""Per-episode records and the per-generator summary of ``seal eval generators`` (thesis Table 6.2 columns).

Summary (scored pass of every scenario): ego success / crash / out-of-road / timeout rates, adversary-induced
collision rate (the ego touched the adversary), realism Wasserstein distances of the executed adversary against
the logged one (yaw rate, acceleration, out-of-road rate, mean), collision speed along the contact normal,
head-on and severe head-on rates, and generation time (mean and p95 over every generation call).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from seal.core.geometry import box_corners, box_gap
from seal.core.outcome import OUTCOMES
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, VALID, WIDTH, Scenario, X, Y
from seal.envs.road_geometry import get_road_geometry
from seal.envs.rollout import Rollout
from seal.scoring.realism import acceleration_stats, collision_metrics, jerk_stats, realism_wd

OFFROAD_TOLERANCE_M = 0.5
"""A box corner may stick out of the drivable area this far (as in `ScenarioEnv`)."""
CLOSE_CALL_M = 2.0
"""An episode is a close call when the ego and the adversary touch or their boxes come within this gap (m)."""


def min_box_gap(ego_track: np.ndarray, adv_track: np.ndarray) -> float:
    """Smallest gap (m) between the ego's and the adversary's boxes over the steps where both are valid (0 on
    contact, inf if never both valid); tracks ``[T, 8]`` on the same steps."""
    both = (ego_track[:, VALID] > 0.5) & (adv_track[:, VALID] > 0.5)
    if not both.any():
        return float("inf")
    e, a = ego_track[both], adv_track[both]
    gap = box_gap(box_corners(e[:, X], e[:, Y], e[:, HEADING], e[:, LENGTH], e[:, WIDTH]),
                  box_corners(a[:, X], a[:, Y], a[:, HEADING], a[:, LENGTH], a[:, WIDTH]))
    return float(gap.min())


def offroad_flags(scenario: Scenario, track: np.ndarray, tolerance_m: float = OFFROAD_TOLERANCE_M) -> np.ndarray:
    """Per valid step of ``track [T, 8]``: True where a box corner leaves the drivable area by > ``tolerance_m``."""
    geom = get_road_geometry(scenario.road)
    rows = track[track[:, VALID] > 0.5]
    corners = box_corners(rows[:, X], rows[:, Y], rows[:, HEADING], rows[:, LENGTH], rows[:, WIDTH])
    return np.array([not geom.on_road(c[:, 0], c[:, 1], tolerance_m) for c in corners], dtype=bool)


@dataclass
class EpisodeRecord:
    """The scored pass of one scenario under one generator.

    Attributes:
        scenario_id, layout, generator: what was played.
        outcome: the ego's outcome (`OUTCOMES`).
        adv_collision: the ego touched the adversary.
        route_completion: ego route completion.
        first_crash_step: scenario step of the ego's first crash, or None.
        predicted_step: the generator's predicted collision / closest-approach step of the scored pass, or None.
        chosen_candidate: the scored pass's chosen candidate, or None.
        generation_times_s: every generation call of this scenario (all K passes).
        ego_track, adv_track: ``[T, 8]`` executed tracks from `CURRENT_STEP` to the last step.
        adv_offroad: per valid step of ``adv_track``, off the road.
        extra: the scored generation's JSON-serialisable details.
    """

    scenario_id: str
    layout: str
    generator: str
    outcome: str
    adv_collision: bool
    route_completion: float
    first_crash_step: int | None
    predicted_step: int | None
    chosen_candidate: int | None
    generation_times_s: list[float]
    ego_track: np.ndarray
    adv_track: np.ndarray
    adv_offroad: np.ndarray
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_rollout(
        cls, scenario: Scenario, generator: str, rollout: Rollout, generation_times_s: Sequence[float],
        predicted_step: int | None = None, chosen_candidate: int | None = None, extra: dict[str, Any] | None = None,
    ) -> EpisodeRecord:
        window = slice(CURRENT_STEP, rollout.last_step + 1)
        adv_track = rollout.adv_track[window].astype(np.float64)
        return cls(
            scenario_id=scenario.scenario_id,
            layout=scenario.layout,
            generator=generator,
            outcome=rollout.outcome,
            adv_collision=any(other == rollout.adv_id for _, other in rollout.ego_crashes),
            route_completion=float(rollout.route_completion),
            first_crash_step=rollout.first_crash_step,
            predicted_step=predicted_step,
            chosen_candidate=chosen_candidate,
            generation_times_s=[float(t) for t in generation_times_s],
            ego_track=rollout.ego_track[window].astype(np.float64),
            adv_track=adv_track,
            adv_offroad=offroad_flags(scenario, adv_track),
            extra=dict(extra or {}),
        )

    def row(self) -> dict[str, Any]:
        """Flat JSON/CSV row (no tracks); scalar ``extra`` entries are appended as ``extra_<key>``."""
        times = np.asarray(self.generation_times_s)
        extras = {f"extra_{k}": v for k, v in self.extra.items() if isinstance(v, bool | int | float | str)}
        return {
            "scenario_id": self.scenario_id,
            "layout": self.layout,
            "generator": self.generator,
            "outcome": self.outcome,
            "adv_collision": self.adv_collision,
            "route_completion": round(self.route_completion, 4),
            "first_crash_step": self.first_crash_step,
            "predicted_step": self.predicted_step,
            "chosen_candidate": self.chosen_candidate,
            "adv_offroad_share": round(float(self.adv_offroad.mean()), 4) if self.adv_offroad.size else 0.0,
            "generation_ms_mean": round(1e3 * float(times.mean()), 3) if times.size else None,
            **extras,
        }


@dataclass(frozen=True)
class LoggedAdversary:
    """The original adversary of a scenario, as realism reference: its logged track from `CURRENT_STEP` on and
    its per-step off-road flags."""

    track: np.ndarray
    offroad: np.ndarray

    @classmethod
    def of(cls, scenario: Scenario) -> LoggedAdversary:
        track = scenario.track(scenario.adv_id)[CURRENT_STEP:].astype(np.float64)
        return cls(track=track, offroad=offroad_flags(scenario, track))


def summarize(records: Sequence[EpisodeRecord], logged: Sequence[LoggedAdversary]) -> dict[str, Any]:
    """One table row for one generator: ``records`` are its scored passes, ``logged`` the original adversaries
    of the same scenarios."""
    n = len(records)
    if n == 0:
        raise ValueError("summarize: no episodes")
    rates = {f"{k}_rate": sum(r.outcome == k for r in records) / n for k in OUTCOMES}
    realism = realism_wd(
        [r.adv_track for r in records], [g.track for g in logged],
        [r.adv_offroad for r in records], [g.offroad for g in logged],
    )
    coll = collision_metrics([r.ego_track for r in records], [r.adv_track for r in records])
    times = np.concatenate([np.asarray(r.generation_times_s, dtype=np.float64) for r in records])
    return {
        "generator": records[0].generator,
        "scenarios": n,
        **rates,
        "adv_collision_rate": sum(r.adv_collision for r in records) / n,
        "close_call_rate": sum(r.adv_collision or min_box_gap(r.ego_track, r.adv_track) <= CLOSE_CALL_M
                               for r in records) / n,
        "route_completion": float(np.mean([r.route_completion for r in records])),
        **realism,
        **jerk_stats([r.adv_track for r in records], [g.track for g in logged]),
        **acceleration_stats([r.adv_track for r in records], [g.track for g in logged]),
        "collision_speed_mps": coll["collision_speed_mps"],
        "head_on_rate": coll["head_on_rate"],
        "severe_head_on_rate": coll["severe_head_on_rate"],
        "generation_ms_mean": 1e3 * float(times.mean()) if times.size else float("nan"),
        "generation_ms_p95": 1e3 * float(np.percentile(times, 95)) if times.size else float("nan"),
        "generations": int(times.size),
    }


TABLE_COLUMNS = (
    ("generator", "generator", "{}"),
    ("scenarios", "n", "{}"),
    ("success_rate", "success", "{:.1%}"),
    ("crash_rate", "crash", "{:.1%}"),
    ("out_of_road_rate", "out of road", "{:.1%}"),
    ("adv_collision_rate", "adv. collision", "{:.1%}"),
    ("close_call_rate", "close call (< 2 m)", "{:.1%}"),
    ("yaw_wd", "yaw WD", "{:.3f}"),
    ("acc_wd", "acc WD", "{:.3f}"),
    ("road_wd", "road WD", "{:.3f}"),
    ("realism", "realism", "{:.3f}"),
    ("acc_mean_mps2", "acc mean (m/s^2)", "{:.2f}"),
    ("logged_acc_mean_mps2", "logged acc mean", "{:.2f}"),
    ("hard_brake_share", "hard brake (< -3 m/s^2)", "{:.1%}"),
    ("logged_hard_brake_share", "logged hard brake", "{:.1%}"),
    ("jerk_wd", "jerk WD", "{:.2f}"),
    ("jerk_abs_p95", "|jerk| p95", "{:.1f}"),
    ("logged_jerk_abs_p95", "logged |jerk| p95", "{:.1f}"),
    ("collision_speed_mps", "coll. speed (m/s)", "{:.2f}"),
    ("head_on_rate", "head-on", "{:.1%}"),
    ("severe_head_on_rate", "severe head-on", "{:.1%}"),
    ("generation_ms_mean", "gen. ms mean", "{:.2f}"),
    ("generation_ms_p95", "gen. ms p95", "{:.2f}"),
)


def format_markdown_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[tuple[str, str, str]]) -> str:
    """``rows`` as a Markdown table, one column per (key, label, format string): the first column left-aligned,
    the others right-aligned; a missing or non-finite value shows as "-"."""
    lines = ["| " + " | ".join(label for _, label, _ in columns) + " |", "|---|" + "---:|" * (len(columns) - 1)]
    for row in rows:
        cells = []
        for key, _, fmt in columns:
            value = row.get(key)
            missing = value is None or (isinstance(value, float) and not math.isfinite(value))
            cells.append("-" if missing else fmt.format(value))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """The summary rows as a Markdown table (NaN shown as "-")."""
    return format_markdown_table(rows, TABLE_COLUMNS)
