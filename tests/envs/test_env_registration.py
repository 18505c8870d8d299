"""The env is reachable through the one `seal` import root, even from a project with its own ``envs/`` package."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]

SCRIPT = """
import gymnasium as gym
import scenario_factory as sf
import envs  # the user's own package, not seal's
assert envs.MARKER == "user", envs.__file__
env = gym.make("seal.envs:seal/Scenario-v0", scenarios=[sf.lane_change_scenario()])
obs, info = env.reset(seed=0)
obs, reward, terminated, truncated, info = env.step(env.action_space.sample() * 0)
print(type(env.unwrapped).__module__, obs.shape)
"""


def test_gym_make_by_module_id_with_a_shadowing_envs_package(tmp_path: Path) -> None:
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "__init__.py").write_text('MARKER = "user"\n')
    env = {**os.environ, "PYTHONPATH": str(TESTS)}
    result = subprocess.run([sys.executable, "-c", SCRIPT], cwd=tmp_path, env=env, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.split() == ["seal.envs.scenario_env", "(100,)"]
