"""One episode of a scenario played and written as a top-down video (``.mp4`` through imageio-ffmpeg, or ``.gif``).

Above both `seal.envs.scenario_env` (which plays the episode) and `seal.envs.render` (which draws it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from seal.core.scenario import Scenario
from seal.envs.heuristic import HeuristicDriver
from seal.envs.render import render_rollout, write_video
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv


def render_episode(
    scenario: Scenario,
    out_path: str | Path,
    policy: Any = None,
    adversary: Any = None,
    fps: int = 10,
    terminate_on_crash: bool = True,
    config: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run one episode of ``scenario`` and write a top-down video of it.

    Args:
        policy: ego policy with SB3 ``predict``; None = `seal.envs.heuristic.HeuristicDriver`.
        adversary: `AdversaryBehavior` (or factory); None = replay of the logged adversary.
        config: extra `ScenarioEnv` config.

    Returns:
        ``{"path", "frames", "outcome", "route_completion", "episode_return", "ego_crashes",
        "out_of_road_step", "scenario_id"}``.
    """
    if Path(out_path).suffix.lower() not in (".mp4", ".gif"):
        raise ValueError(f"unsupported video format {Path(out_path).suffix!r}: use .mp4 or .gif")
    policy = policy if policy is not None else HeuristicDriver()
    env = ScenarioEnv([scenario], config={**(config or {}), "terminate_on_crash": terminate_on_crash},
                      adversary=adversary)
    obs, _ = env.reset(seed=0)
    while True:
        action, _ = policy.predict(obs, deterministic=True)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    rollout: Rollout = info["rollout"]
    frames = render_rollout(rollout, scenario.road, scenario)
    path = write_video(frames, out_path, fps)
    return {
        "path": str(path),
        "frames": len(frames),
        "outcome": rollout.outcome,
        "route_completion": rollout.route_completion,
        "episode_return": rollout.episode_return,
        "ego_crashes": rollout.ego_crashes,
        "out_of_road_step": rollout.out_of_road_step,
        "scenario_id": scenario.scenario_id,
    }
