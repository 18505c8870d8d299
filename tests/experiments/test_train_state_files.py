"""The array files and the progress log of a `seal train` run folder (mutation-testing survivors of
`seal.experiments.training.state`, issue 24): a replay buffer file holds only the filled rows and round-trips a
memory-optimised buffer, no array file of a checkpoint is unpickled, and a progress log that is not one line per
row is kept whole."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from gymnasium import spaces

from seal.experiments.training import state as ts

OBS = spaces.Box(-1.0, 1.0, (3,), np.float32)
ACT = spaces.Box(-1.0, 1.0, (2,), np.float32)


def _buffer(rows: int, optimize_memory_usage: bool = False):  # noqa: ANN202
    """An SB3 ReplayBuffer of 8 rows x 1 env with ``rows`` random transitions (seeded)."""
    from stable_baselines3.common.buffers import ReplayBuffer

    buf = ReplayBuffer(8, OBS, ACT, device="cpu", n_envs=1, optimize_memory_usage=optimize_memory_usage,
                       handle_timeout_termination=not optimize_memory_usage)
    rng = np.random.default_rng(rows)
    for _ in range(rows):
        buf.add(rng.uniform(-1, 1, (1, 3)), rng.uniform(-1, 1, (1, 3)), rng.uniform(-1, 1, (1, 2)),
                rng.uniform(size=1), np.array([0.0]), [{}])
    return buf


def test_a_replay_buffer_file_holds_only_the_filled_rows(tmp_path: Path) -> None:
    ts.save_replay_buffer(_buffer(3), tmp_path / "rb.npz")
    with np.load(tmp_path / "rb.npz") as z:
        assert {name: z[name].shape[0] for name in ("observations", "actions", "rewards")} == {
            "observations": 3, "actions": 3, "rewards": 3}
        assert z["meta"].tolist() == [3, 0, 8, 1]  # pos, full, size, n_envs


def test_a_memory_optimised_buffer_round_trips(tmp_path: Path) -> None:
    """SB3 keeps no next_observations array in a memory-optimised buffer: the fields after it still load."""
    src = _buffer(5, optimize_memory_usage=True)
    assert getattr(src, "next_observations", None) is None
    ts.save_replay_buffer(src, tmp_path / "rb.npz")
    dst = _buffer(0, optimize_memory_usage=True)
    ts.load_replay_buffer(dst, tmp_path / "rb.npz")
    assert dst.pos == 5
    for name in ("observations", "actions", "rewards", "dones"):
        np.testing.assert_array_equal(getattr(dst, name), getattr(src, name), err_msg=name)


def _object_array() -> np.ndarray:
    return np.array([{"pickled": True}], dtype=object)


def test_a_replay_buffer_file_with_a_pickled_array_is_refused(tmp_path: Path) -> None:
    ts.save_replay_buffer(_buffer(3), tmp_path / "rb.npz")
    with np.load(tmp_path / "rb.npz") as z:
        arrays = {k: z[k] for k in z.files}
    np.savez(tmp_path / "rb.npz", **{**arrays, "actions": _object_array()})
    with pytest.raises(ValueError, match="allow_pickle=False"):
        ts.load_replay_buffer(_buffer(0), tmp_path / "rb.npz")


@pytest.mark.parametrize("name", ["rng.npz", "worker_0.npz"])
def test_checkpoint_arrays_with_a_pickle_are_refused(tmp_path: Path, name: str) -> None:
    folder = tmp_path / "step_10"
    folder.mkdir()
    (folder / "state.json").write_text(json.dumps({"step": 10, "n_workers": 1}))
    np.savez(folder / "rng.npz", torch=np.zeros(3, np.uint8))
    np.savez(folder / "worker_0.npz", meta=np.zeros(2))
    np.savez(folder / name, payload=_object_array())
    with pytest.raises(ValueError, match="allow_pickle=False"):
        ts.read_checkpoint_state(folder)


@pytest.mark.parametrize("text", [
    "a,b\n1,10\n2,20\n",  # no time/total_timesteps column
    'a,time/total_timesteps\n"two\nlines",10\n2,30\n',  # a quoted field over two lines
])
def test_a_progress_log_that_cannot_be_cut_by_step_is_kept_whole(tmp_path: Path, text: str) -> None:
    path = tmp_path / "progress.csv"
    path.write_text(text)
    ts.truncate_progress(path, 20)
    assert path.read_text() == text
