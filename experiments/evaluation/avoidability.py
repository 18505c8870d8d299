"""``seal eval avoidability``: were an ego's crashes avoidable? A hindsight search over other ego plans.

For each scenario of a setting the ego plays the evaluation protocol exactly as ``seal eval runs`` does
(`seal.experiments.evaluation.protocol`: the normal episode, then the K generator passes; the last one scored). When
the scored episode ends in a crash, the scored pass's adversary behaviour is played again from the same env seed
against other ego plans: the reference ego itself (the crash must come back, else the row says "not reproducible"),
the heuristic driver, and `AvoidabilityConfig.n_plans` plans (`seal.experiments.evaluation.avoidance_plans`): in
the ``actions`` space they drive like the heuristic driver with a piecewise-constant offset added to its
acceleration (and, on some segments, its steering): full braking or full throttle from each segment on, then random
offsets; in the ``skills`` space they are a ReSkill ego's own agent with its skill choices changed the same way. A
crash is *avoidable* when one of them finishes the episode without a crash and on the road, and *avoidable reaching
the goal* when one also completes the route.

What this measures and what it does not: the plans know the adversary's future (it is replayed: open loop for
CAT-style generators, reacting to the plan for SEAL's skills), so "avoidable" is a hindsight bound, what no
reactive driver is promised to reach; and the plans are a sample, so "not avoidable" means "none of the plans
tried avoided it", not a proof. Crashes are split by whom the ego touched: the adversary, or other traffic (which
replays its log and does not react to the ego unless the setting is ``normal-reactive``).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from seal.core.scenario import Scenario
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.avoidance_plans import (
    PLAN_SPACES,
    AvoidabilityConfig,
    PlanEgo,
    SkillPlanEgo,
    ego_plans,
    plan_label,
    plan_offsets,
    skill_plans,
)

__all__ = ["FAILED", "PLAN_SPACES", "AvoidabilityConfig", "PlanEgo", "ProbeRow", "SkillPlanEgo", "plan_label",
           "plan_offsets", "probe_scenario", "run_avoidability", "skill_plans", "summarize"]

FAILED = ("crash", "out_of_road")


@dataclass
class ProbeRow:
    """One scenario's scored episode and, for a crash, what the search found."""

    scenario_id: str
    outcome: str
    crash_with: str = ""
    """``adversary`` (the ego touched the adversary), ``other`` (only other traffic) or empty (no crash)."""
    crash_step: int | None = None
    reproducible: bool | None = None
    """The reference ego crashed again when the adversary was played again from the same seed."""
    heuristic_outcome: str | None = None
    avoidable: bool | None = None
    avoidable_reaching_goal: bool | None = None
    plans_tried: int = 0
    first_avoiding_plan: str = ""
    """`plan_label` of the first plan (in the search's order) that avoided the crash; empty: none."""
    first_goal_plan: str = ""
    """`plan_label` of the first plan that also reached the goal (the search stops there); empty: none."""
    seconds: float = 0.0


def _outcome(rollout: Rollout) -> str:
    return str(getattr(rollout.outcome, "value", rollout.outcome))


def probe_scenario(
    env: ScenarioEnv, scenario: Scenario, index: int, ego: Any, generator: Any, k: int, seed: int,
    config: AvoidabilityConfig,
) -> ProbeRow:
    """The scored episode of the ``index``-th scenario of its split (generator None: the normal episode) and, if it
    crashed, the search of the module docstring."""
    from seal.experiments.evaluation import protocol
    from seal.experiments.evaluation.episodes import run_episode

    start = time.perf_counter()
    normal = protocol.normal_episode(env, scenario, index, ego, seed)
    episode_seed = protocol.episode_seed_of(seed, index)
    behavior, scored = None, normal
    if generator is not None:
        last = protocol.generator_passes(env, scenario, index, ego, generator, k, seed, normal)[-1]
        behavior, scored, episode_seed = last.generation.behavior, last.rollout, last.seed
    row = ProbeRow(scenario.scenario_id, _outcome(scored))
    if row.outcome != "crash":
        row.seconds = round(time.perf_counter() - start, 2)
        return row
    row.crash_with = "adversary" if any(agent == scored.adv_id for _, agent in scored.ego_crashes) else "other"
    row.crash_step = int(scored.ego_crashes[0][0]) if scored.ego_crashes else None
    again = run_episode(env, scenario, ego, behavior, seed=episode_seed)
    row.reproducible = _outcome(again) == row.outcome and again.ego_crashes == scored.ego_crashes
    if row.reproducible:
        row.heuristic_outcome = _outcome(run_episode(env, scenario, PlanEgo(np.zeros((1, 2)), 1), behavior,
                                                     seed=episode_seed))
        # The heuristic driver is the first plan of the actions space; the skills space searches the ego's own.
        labels, outcomes = (["heuristic"], [row.heuristic_outcome]) if config.plan_space == "actions" else ([], [])
        segment_steps = int(np.ceil(int(env.config["horizon_steps"]) / config.segments))
        for label, plan in ego_plans(config, ego, index, segment_steps):
            if "success" in outcomes:
                break
            labels.append(label)
            outcomes.append(_outcome(run_episode(env, scenario, plan, behavior, seed=episode_seed)))
            row.plans_tried += 1
        row.avoidable = any(o not in FAILED for o in outcomes)
        row.avoidable_reaching_goal = "success" in outcomes
        row.first_avoiding_plan = next((lab for lab, o in zip(labels, outcomes, strict=True) if o not in FAILED), "")
        row.first_goal_plan = next((lab for lab, o in zip(labels, outcomes, strict=True) if o == "success"), "")
    row.seconds = round(time.perf_counter() - start, 2)
    return row


def summarize(rows: Sequence[ProbeRow]) -> dict[str, Any]:
    """Counts and shares: crashes by whom the ego touched, and of the reproducible ones how many were avoidable."""
    out: dict[str, Any] = {"scenarios": len(rows), "crashes": sum(r.outcome == "crash" for r in rows)}
    for group in ("adversary", "other"):
        crashed = [r for r in rows if r.crash_with == group]
        checked = [r for r in crashed if r.reproducible]
        n = len(checked)
        out[group] = {
            "crashes": len(crashed), "reproducible": n,
            "avoidable": sum(bool(r.avoidable) for r in checked),
            "avoidable_reaching_goal": sum(bool(r.avoidable_reaching_goal) for r in checked),
            "heuristic_avoids": sum(r.heuristic_outcome not in FAILED for r in checked),
            # How the goal was reached: the kind of the first plan that did (heuristic, brake, throttle, random).
            "first_goal_plan": dict(sorted(Counter(r.first_goal_plan.split("@")[0] for r in checked
                                                   if r.first_goal_plan).items())),
            "avoidable_share": round(sum(bool(r.avoidable) for r in checked) / n, 4) if n else None,
            "avoidable_reaching_goal_share": (
                round(sum(bool(r.avoidable_reaching_goal) for r in checked) / n, 4) if n else None),
        }
    return out


CHUNK_SCENARIOS = 4
"""Scenarios per job when the probe is spread over worker processes."""


def probe_chunk(job: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Probe the scenarios ``job["indices"]`` of a setting (a backend job; keys: ``ego``, ``algo``, ``setting``
    (`Setting` fields), ``config``, ``search`` (`AvoidabilityConfig` fields), ``session``); rows as dicts with
    their scenario index."""
    from seal.core.workers import torch_threads
    from seal.experiments.evaluation.evaluate import Setting
    from seal.experiments.evaluation.worker_cache import (
        cached_ego,
        cached_env,
        cached_generator,
        cached_split,
        use_session,
    )

    torch_threads(1)
    use_session(str(job["session"]))
    setting, config = Setting(**job["setting"]), job["config"]
    search = AvoidabilityConfig(**job["search"])
    env = cached_env(setting.dataset, setting.split, config, reactive=setting.reactive)
    scenarios = cached_split(setting.dataset, setting.split, config.get("limit"))
    ego = cached_ego(job["ego"], job.get("algo"))
    generator = (cached_generator(job["ego"], setting.generator, config, setting=setting.name)
                 if setting.generator else None)
    rows = []
    for index in job["indices"]:
        row = probe_scenario(env, scenarios[index], index, ego, generator, int(config["k"]), int(config["seed"]),
                             search)
        rows.append({"index": index, **row_dicts([row])[0]})
    return rows


def run_avoidability(
    ego_spec: str, setting: Any, config: Mapping[str, Any], search: AvoidabilityConfig, algo: str | None = None,
    progress: bool = True, workers: int = 1,
) -> list[ProbeRow]:
    """Probe every scenario of ``setting`` (a `seal.experiments.evaluation.evaluate.Setting`; ``config``: a resolved
    eval config with its ``generators``) for the ego ``ego_spec`` (`make_ego`'s spec), in chunks of
    `CHUNK_SCENARIOS` over ``workers`` processes (1: this one). A scenario's episodes and plans depend only on the
    scenario, its index, the ego, the generator and the seeds, so the rows are the same for any ``workers``."""
    import dataclasses
    import uuid

    from seal.experiments.backends import InlineBackend, LocalBackend
    from seal.experiments.evaluation.worker_cache import cached_split

    n = len(cached_split(setting.dataset, setting.split, config.get("limit")))
    session = uuid.uuid4().hex
    common = {"ego": ego_spec, "algo": algo, "setting": dataclasses.asdict(setting), "config": dict(config),
              "search": dataclasses.asdict(search), "session": session}
    jobs: list[dict[str, Any]] = [{**common, "indices": list(range(i, min(i + CHUNK_SCENARIOS, n)))}
                                  for i in range(0, n, CHUNK_SCENARIOS)]
    backend: Any = LocalBackend(workers) if workers > 1 else InlineBackend()
    results = backend.map(probe_chunk, jobs, desc=f"avoidability {setting.name}", unit="scenario",
                          sizes=[len(j["indices"]) for j in jobs], progress=progress)
    failed = [r for r in results if not r.ok]
    if failed:
        raise RuntimeError(f"avoidability: {len(failed)} of {len(jobs)} chunks failed; first: {failed[0].error}")
    rows = sorted((row for r in results for row in r.value), key=lambda row: row["index"])
    return [ProbeRow(**{k: v for k, v in row.items() if k != "index"}) for row in rows]


def row_dicts(rows: Sequence[ProbeRow]) -> list[dict[str, Any]]:
    """Rows as flat dicts (CSV / JSON)."""
    return [asdict(r) for r in rows]


def format_summary(summary: Mapping[str, Any], ego: str, setting: str) -> str:
    """The summary as a small table."""
    space = (summary.get("search") or {}).get("plan_space", "actions")
    lines = [f"ego {ego}, setting {setting}: {summary['crashes']} crashes in {summary['scenarios']} scenarios "
             f"(plans in the {space} space)",
             f"{'crashes with':<16}{'n':>6}{'replayed':>10}{'avoidable':>16}{'...reaching goal':>18}"
             f"{'heuristic avoids':>18}"]
    for group, label in (("adversary", "the adversary"), ("other", "other traffic")):
        g = summary[group]
        n = g["reproducible"] or 1
        lines.append(f"{label:<16}{g['crashes']:>6}{g['reproducible']:>10}"
                     f"{g['avoidable']:>7} ({100 * g['avoidable'] / n:4.1f} %)"
                     f"{g['avoidable_reaching_goal']:>9} ({100 * g['avoidable_reaching_goal'] / n:4.1f} %)"
                     f"{g['heuristic_avoids']:>18}")
    for group, label in (("adversary", "the adversary"), ("other", "other traffic")):
        kinds = summary[group].get("first_goal_plan") or {}
        if kinds:
            lines.append(f"reaching the goal past {label}, first by: "
                         + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items(), key=lambda kv: -kv[1])))
    lines.append("avoidable = some ego plan, knowing the adversary's future, ends without a crash and on the road "
                 "(a hindsight bound)")
    return "\n".join(lines)
