"""Top-down rendering: frames show the road and the coloured vehicles; videos are written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from seal.core.scenario import CURRENT_STEP, N_STEPS, Scenario
from seal.envs.behaviors import ReplayBehavior
from seal.envs.episode_video import render_episode
from seal.envs.render import ADV, EGO, OTHER, render_rollout
from seal.envs.scenario_env import ScenarioEnv


def _has_color(frame: np.ndarray, color: tuple[int, int, int]) -> bool:
    return bool((np.abs(frame.astype(int) - color).sum(-1) < 10).any())


def _parked(scenario: Scenario) -> ReplayBehavior:
    """The adversary parked 70 m ahead in the ego's lane."""
    ego = scenario.track(scenario.ego_id)[CURRENT_STEP]
    track = np.zeros((N_STEPS, 8))
    track[:] = (ego[0] + 70.0, ego[1], 0.0, 0.0, 0.0, 5.0, 2.0, 1.0)
    return ReplayBehavior(track)


def test_frames_show_road_and_vehicles(lane_change: Scenario) -> None:
    env = ScenarioEnv([lane_change])
    env.reset()
    done = False
    while not done:
        *_, terminated, truncated, info = env.step(np.zeros(2))
        done = terminated or truncated
    frames = render_rollout(info["rollout"], lane_change.road, lane_change)
    assert len(frames) == info["rollout"].n_steps + 1
    f = frames[0]
    assert f.shape[0] % 16 == 0 and f.shape[1] % 16 == 0 and f.dtype == np.uint8
    assert f.std() > 10  # not blank
    assert _has_color(f, EGO) and _has_color(f, ADV) and _has_color(f, OTHER)
    assert _has_color(f, (255, 255, 255))  # lane markings


def test_render_episode_writes_videos(stopped_adv: Scenario, tmp_path: Path) -> None:
    out = tmp_path / "ep.mp4"
    summary = render_episode(stopped_adv, out, adversary=_parked(stopped_adv))
    assert out.exists() and out.stat().st_size > 1000
    # The heuristic ego stops behind the parked adversary: no crash, the episode runs to the time limit.
    assert summary["outcome"] == "timeout" and summary["frames"] == 91
    # Driving straight on, it hits it (a short episode: also the .gif path).
    out = tmp_path / "ep.gif"
    summary = render_episode(stopped_adv, out, policy=_Straight(), adversary=_parked(stopped_adv))
    assert out.exists() and summary["outcome"] == "crash" and summary["ego_crashes"]
    with pytest.raises(ValueError, match="mp4 or .gif"):
        render_episode(stopped_adv, tmp_path / "ep.avi", policy=_Straight(), adversary=_parked(stopped_adv))


class _Straight:
    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros(2, dtype=np.float32), state


def test_a_long_title_is_wrapped_to_a_narrow_frame(lane_change: Scenario) -> None:
    from seal.envs.render import FrameRenderer

    renderer = FrameRenderer(lane_change.road, bounds=(0.0, -10.0, 40.0, 20.0), max_frame=(160, 720))
    title = "USA_Lanker-1_1_T-1-03 heuristic ego vs replayed adversary: out_of_road at step 19\nsecond line"
    lines = renderer.wrap_text(title)
    assert len(lines) > 2 and lines[-1] == "second line"
    assert all(renderer._font.size(line)[0] <= renderer.size[0] - 12 for line in lines)
    assert " ".join(lines[:-1]) == title.split("\n")[0]  # nothing lost, only broken at spaces
    frame = renderer.draw_state(lane_change.tracks[:, CURRENT_STEP], 0, 1, text=title)
    assert frame.shape[1] == renderer.size[0]
