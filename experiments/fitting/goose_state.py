"""Checkpoints of ``seal fit goose``: what a killed fit goes on from.

The fit learns in chunks of ``checkpoint_every`` roll-outs (`seal.experiments.fitting.goose`); after each chunk the
run folder gets ``checkpoint/`` with::

    state.json   settings fingerprint, env steps done, SB3 update / episode counters, training seconds so far, the
                 success-curve tracker, the held-out baseline (zero / random / untrained policies) and rng states
    model.zip    SB3 parameters and optimiser states (``torch.load(weights_only=True)``; the pickled settings are
                 never read: the model is rebuilt from the config)
    buffer.npz   the HER replay buffer's filled part (dict observations, episode starts and lengths)
    env.npz      `GooseEnv.get_state` (env rng, the running episode's curve edit) and SB3's last observation
    rng.npz      numpy / torch rng arrays

It is written into a temporary folder and renamed (a kill leaves the previous checkpoint whole), and removed once the
agent is saved. A fit run again with the same settings (config, dataset, agent file) loads it and writes the same
agent as an uninterrupted fit; other settings, or a checkpoint that does not read back, start over (with a warning
naming why). Arrays are loaded with ``allow_pickle=False``; nothing here is unpickled.
"""

from __future__ import annotations

import json
import logging
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.atomic import atomic_write_json
from seal.experiments.training import state as ts

logger = logging.getLogger(__name__)

CHECKPOINT = "checkpoint"
_BUFFER_ARRAYS = ("actions", "rewards", "dones", "timeouts", "ep_start", "ep_length")
_OBS_PREFIX = ("observations", "next_observations")


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _monitor(model: Any) -> Any:
    """SB3's ``Monitor`` around the fit's env (it refuses a step before a reset, and sums the episode's rewards)."""
    env = model.env.envs[0]
    while not hasattr(env, "needs_reset"):
        env = env.env
    return env


def save_her_buffer(buffer: Any, path: Path) -> None:
    """The filled part of an SB3 ``HerReplayBuffer`` (dict observations) as an ``.npz``."""
    n = buffer.buffer_size if buffer.full else buffer.pos
    arrays = {name: np.asarray(getattr(buffer, name))[:n] for name in _BUFFER_ARRAYS}
    for prefix in _OBS_PREFIX:
        for key, value in getattr(buffer, prefix).items():
            arrays[f"{prefix}/{key}"] = np.asarray(value)[:n]
    arrays["current_ep_start"] = np.asarray(buffer._current_ep_start)
    arrays["meta"] = np.array([buffer.pos, int(buffer.full), buffer.buffer_size, buffer.n_envs], dtype=np.int64)
    ts.write_npz(path, arrays)


def load_her_buffer(buffer: Any, path: Path) -> None:
    """Fill ``buffer`` (built with the fit's settings) from `save_her_buffer`'s file."""
    z = _read_npz(path)
    pos, full, size, n_envs = (int(v) for v in z["meta"])
    if (size, n_envs) != (buffer.buffer_size, buffer.n_envs):
        raise ValueError(f"{path}: replay buffer of size {size} x {n_envs} envs, the fit's is "
                         f"{buffer.buffer_size} x {buffer.n_envs}")
    for name in _BUFFER_ARRAYS:
        data = z[name]
        getattr(buffer, name)[: len(data)] = data
    for prefix in _OBS_PREFIX:
        target = getattr(buffer, prefix)
        for key in target:
            data = z[f"{prefix}/{key}"]
            target[key][: len(data)] = data
    buffer._current_ep_start[:] = z["current_ep_start"]
    buffer.pos, buffer.full = pos, bool(full)


def write_checkpoint(run: Path, model: Any, env: Any, extra: dict[str, Any]) -> None:
    """Checkpoint the fit (module docstring) into ``run/checkpoint``; ``extra`` goes into ``state.json``."""
    final, tmp = run / CHECKPOINT, run / f".tmp_{CHECKPOINT}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    model.save(tmp / "model.zip", exclude=ts.SAVE_EXCLUDE)
    save_her_buffer(model.replay_buffer, tmp / "buffer.npz")
    last_obs = {f"obs/{k}": np.asarray(v) for k, v in model._last_obs.items()}
    monitor = {"monitor_rewards": np.asarray(_monitor(model).rewards, dtype=np.float64)}
    ts.write_npz(tmp / "env.npz", {**env.get_state(), **last_obs, **monitor})
    rng_json, rng_arrays = ts.rng_state(model)
    ts.write_npz(tmp / "rng.npz", rng_arrays)
    atomic_write_json(tmp / "state.json", {
        "step": int(model.num_timesteps), "n_updates": int(model._n_updates), "episode_num": int(model._episode_num),
        "rng": rng_json, **extra,
    })
    old = run / f".old_{CHECKPOINT}"
    if final.exists():
        shutil.rmtree(old, ignore_errors=True)
        final.rename(old)
    tmp.rename(final)
    shutil.rmtree(old, ignore_errors=True)


def _folder(run: Path) -> Path:
    """The checkpoint folder; the previous one when a kill came between the two renames of `write_checkpoint`."""
    final, old = run / CHECKPOINT, run / f".old_{CHECKPOINT}"
    return old if not final.exists() and old.exists() else final


def read_checkpoint(run: Path, fingerprint: str) -> dict[str, Any] | None:
    """``state.json`` of ``run``'s checkpoint when it was written with ``fingerprint`` and every file reads back;
    None otherwise (no checkpoint, other settings, damaged: the fit starts over; the reason is logged)."""
    folder = _folder(run)
    path = folder / "state.json"
    if not path.is_file():
        return None
    try:
        state = json.loads(path.read_text())
        if state.get("fingerprint") != fingerprint:
            logger.warning(f"{folder} was written with other settings (config, dataset or agent file): starting over")
            return None
        for name in ("model.zip", "buffer.npz", "env.npz", "rng.npz"):
            ts.check_zip_whole(folder / name)
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
        logger.warning(f"{folder} does not read back ({type(exc).__name__}: {exc}): starting over")
        return None
    return dict(state)


def restore(run: Path, model: Any, env: Any, state: dict[str, Any]) -> None:
    """Load ``run``'s checkpoint (read by `read_checkpoint`) into a model and env built with the same settings."""
    folder = _folder(run)
    ts.load_model_state(model, folder / "model.zip")
    load_her_buffer(model.replay_buffer, folder / "buffer.npz")
    arrays = _read_npz(folder / "env.npz")
    env.set_state({k: v for k, v in arrays.items() if not k.startswith("obs/") and k != "monitor_rewards"})
    monitor = _monitor(model)
    monitor.needs_reset, monitor.rewards = False, [float(r) for r in arrays["monitor_rewards"]]
    model._last_obs = {k[4:]: v for k, v in arrays.items() if k.startswith("obs/")}
    model.num_timesteps = int(state["step"])
    model._n_updates = int(state["n_updates"])
    model._episode_num = int(state["episode_num"])
    ts.set_rng_state(model, state["rng"], _read_npz(folder / "rng.npz"))


def remove(run: Path) -> None:
    """Drop the checkpoint (the agent is saved)."""
    for name in (CHECKPOINT, f".tmp_{CHECKPOINT}", f".old_{CHECKPOINT}"):
        shutil.rmtree(run / name, ignore_errors=True)
