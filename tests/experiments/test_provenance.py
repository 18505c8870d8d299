"""Run provenance: every generator option with the value it got, the code version from a git checkout (commit,
dirty flag, None outside one) and one entry per training session."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from seal.adversaries.rcg.select import DEFAULT_PRIOR_WEIGHT as RCG_WEIGHT
from seal.adversaries.seal.objective import DEFAULT_PRIOR_WEIGHT as SEAL_WEIGHT
from seal.experiments.training.provenance import PROVENANCE, append_session, code_version, generator_options


def test_generator_options_fill_in_the_defaults_the_config_leaves_out() -> None:
    seal = generator_options("seal", {"objective": "cat", "noise_scale": 0.5})
    assert seal["objective"] == "cat" and seal["noise_scale"] == 0.5
    assert seal["prior_weight"] == SEAL_WEIGHT and seal["switch"] == "adversarial" and seal["switch_offset_steps"] == 10
    assert generator_options("cat-rcg", {"behavior": "b.pt"})["prior_weight"] == RCG_WEIGHT
    odd = generator_options("replay", {"extra": (1, Path("x"))})  # not in the signature: kept, as plain data
    assert odd == {"extra": [1, "x"]}


@pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")
def test_code_version_reads_the_checkout(tmp_path: Path) -> None:
    assert code_version(tmp_path)["git_commit"] is None  # not a checkout
    repo = tmp_path / "repo"
    repo.mkdir()

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout

    git("init", "-q")
    (repo / "a.txt").write_text("1")
    git("add", "a.txt")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "one")
    head = git("rev-parse", "HEAD").strip()
    clean = code_version(repo)
    assert clean["git_commit"] == head and clean["git_dirty"] is False
    (repo / "new.txt").write_text("untracked files do not count")
    assert code_version(repo)["git_dirty"] is False
    (repo / "a.txt").write_text("2")
    assert code_version(repo)["git_dirty"] is True


def test_sessions_are_appended_and_a_damaged_file_starts_again(tmp_path: Path) -> None:
    config = {"generator": {"name": "cat", "kwargs": {"prior": "p.pt"}}}
    append_session(tmp_path, config)
    second = append_session(tmp_path, {"generator": {"name": None, "kwargs": {}}})
    sessions = json.loads((tmp_path / PROVENANCE).read_text())["sessions"]
    assert len(sessions) == 2 and sessions[0]["generator"]["options"]["prior"] == "p.pt"
    assert second["generator"] is None and sessions[1] == second
    assert set(sessions[0]["libraries"]) >= {"torch", "stable-baselines3", "gymnasium"}
    (tmp_path / PROVENANCE).write_text("{not json")
    append_session(tmp_path, config)
    assert len(json.loads((tmp_path / PROVENANCE).read_text())["sessions"]) == 1
