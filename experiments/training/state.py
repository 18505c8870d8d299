"""Run folder of ``seal train`` and its checkpoints (what a killed run resumes from).

Layout of a run folder ``RUN/``::

    config.yaml           resolved config (seal.experiments.training.config)
    provenance.json       one entry per training session: code version (git commit), library versions, every
                          generator option with the value it got (seal.experiments.training.provenance)
    progress.csv          SB3 CSV log (rows after the resumed checkpoint are dropped on resume)
    tb/                   TensorBoard event files (a resumed session adds a file; the killed session's points
                          after its last checkpoint stay in the older one)
    eval/                 evaluations.csv (one row per evaluation) and step_<N>.json (per-scenario outcomes)
    checkpoints/latest.json   {"step": N, "dir": "step_<N>"}: the last complete checkpoint
    checkpoints/step_<N>/ model.zip (SB3: parameters + optimiser states), replay_buffer.npz (off-policy),
                          state.json (counters, wall time, rng states as JSON), rng.npz (numpy / torch rng arrays),
                          worker_<i>.npz (each env worker's roll-out queues and env rng: `ClosedLoopEnv.get_state`)
    final_model.zip       the trained model, once finished
    done.json             {"steps": N, "wall_s": ...}, written last (atomically): the run is finished

A checkpoint is written into a temporary folder, renamed to ``step_<N>`` and only then named in ``latest.json``
(atomic write), so a kill at any moment leaves the previous complete checkpoint in force. A damaged
``latest.json`` or checkpoint file (disk errors, a hand edit) is named and the run resumes from the newest
checkpoint that reads back whole (`latest_checkpoint`). Nothing here is
unpickled: arrays are loaded with ``allow_pickle=False`` and the model's parameters with SB3's
``torch.load(weights_only=True)``; the model's pickled settings are never read (the model is rebuilt from
``config.yaml``).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import random
import shutil
import zipfile
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.atomic import atomic_write, atomic_write_bytes, atomic_write_json, naming_the_file
from seal.core.errors import SealError

logger = logging.getLogger(__name__)

CONFIG = "config.yaml"
DONE = "done.json"
FINAL_MODEL = "final_model.zip"
PROGRESS = "progress.csv"
CHECKPOINTS = "checkpoints"
LATEST = "latest.json"
KEEP_CHECKPOINTS = 2

SAVE_EXCLUDE = [
    "action_noise", "_last_obs", "_last_original_obs", "_last_episode_starts", "ep_info_buffer",
    "ep_success_buffer", "_episode_storage", "replay_buffer_kwargs", "lr_schedule",
]
"""Model attributes left out of saved zips: pickled-only runtime state (the model is rebuilt from the config)."""

_BUFFER_FIELDS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


class RunFolderError(ValueError):
    """A run folder cannot be used as asked (finished, unfinished without --resume, not a run)."""


def run_status(out: Path) -> str:
    """``"new"`` (absent or empty), ``"done"`` (has done.json), ``"unfinished"`` (has config.yaml) or
    ``"foreign"`` (a non-empty folder that is not a run)."""
    out = Path(out)
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        return "new"
    if (out / DONE).is_file():
        return "done"
    if (out / CONFIG).is_file():
        return "unfinished"
    return "foreign"


def check_out_folder(out: Path, resume: bool) -> str:
    """The folder's `run_status`, or a `RunFolderError` telling the user what to do."""
    status = run_status(out)
    if status == "done":
        raise RunFolderError(f"{out} holds a finished run ({DONE}); it is never overwritten: choose another --out")
    if status == "foreign":
        raise RunFolderError(f"{out} is not empty and is not a `seal train` run folder ({CONFIG} missing)")
    if resume and status == "new":
        raise RunFolderError(f"--resume {out}: no run there to resume (no {CONFIG}); start one with --out")
    if not resume and status == "unfinished":
        raise RunFolderError(
            f"{out} holds an unfinished run; continue it with `seal train --resume {out}` or choose another --out"
        )
    return status


# --------------------------------------------------------------------------------------------------- writes
def save_replay_buffer(buffer: Any, path: Path) -> None:
    """The filled part of an SB3 ``ReplayBuffer`` as an ``.npz`` (arrays only; ``pos``, ``full`` and the buffer
    size recorded for the checks of `load_replay_buffer`)."""
    n = buffer.buffer_size if buffer.full else buffer.pos
    # A memory-optimised buffer keeps no next_observations: the last transition's is the observation row after it.
    n_obs = n + 1 if getattr(buffer, "optimize_memory_usage", False) and not buffer.full else n
    arrays: dict[str, Any] = {name: np.asarray(getattr(buffer, name))[: n_obs if name == "observations" else n]
                              for name in _BUFFER_FIELDS if getattr(buffer, name, None) is not None}
    arrays["meta"] = np.array([buffer.pos, int(buffer.full), buffer.buffer_size, buffer.n_envs], dtype=np.int64)
    atomic_write(path, lambda f: np.savez(f, **arrays))


def load_replay_buffer(buffer: Any, path: Path) -> None:
    """Fill ``buffer`` (built with the run's settings) from `save_replay_buffer`'s file."""
    with np.load(path, allow_pickle=False) as z:
        pos, full, size, n_envs = (int(v) for v in z["meta"])
        if (size, n_envs) != (buffer.buffer_size, buffer.n_envs):
            raise ValueError(f"{path}: replay buffer of size {size} x {n_envs} envs, the run's is "
                             f"{buffer.buffer_size} x {buffer.n_envs}")
        for name in _BUFFER_FIELDS:
            target = getattr(buffer, name, None)
            if target is None:
                continue
            if name not in z.files:
                raise ValueError(f"{path}: no {name!r} array")
            data = z[name]
            target[: len(data)] = data
        buffer.pos, buffer.full = pos, bool(full)


def write_npz(path: Path, arrays: Mapping[str, Any], compressed: bool = False) -> None:
    """``arrays`` as an ``.npz`` at ``path``, atomically."""
    save: Any = np.savez_compressed if compressed else np.savez
    atomic_write(path, lambda f: save(f, **arrays))


def rng_state(model: Any) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Global (numpy legacy, python, torch) and action-space rng states: JSON part and array part."""
    import torch

    name, keys, pos, has_gauss, cached = np.random.get_state()
    version, internal, gauss = random.getstate()
    json_part = {
        "numpy": {"name": name, "pos": int(pos), "has_gauss": int(has_gauss), "cached_gaussian": float(cached)},
        "python": {"version": version, "internal": list(internal), "gauss": gauss},
        "action_space": model.action_space.np_random.bit_generator.state,
    }
    arrays = {"numpy_keys": np.asarray(keys, dtype=np.uint32), "torch": torch.get_rng_state().numpy()}
    return json_part, arrays


def set_rng_state(model: Any, json_part: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    import torch

    n = json_part["numpy"]
    np.random.set_state((n["name"], arrays["numpy_keys"], n["pos"], n["has_gauss"], n["cached_gaussian"]))
    p = json_part["python"]
    random.setstate((p["version"], tuple(p["internal"]), p["gauss"]))
    torch.set_rng_state(torch.from_numpy(np.asarray(arrays["torch"], dtype=np.uint8)))
    model.action_space.np_random.bit_generator.state = json_part["action_space"]


def write_checkpoint(out: Path, model: Any, worker_states: list[dict[str, np.ndarray]], extra: dict[str, Any],
                     extra_models: Mapping[str, Any] | None = None) -> Path:
    """Write checkpoint ``step_<num_timesteps>`` (module docstring), point ``latest.json`` at it and drop all but
    the last `KEEP_CHECKPOINTS` (replay buffers only in the newest). ``extra_models`` (name -> SB3 model: the
    ReSkill ego's residual agent) are saved beside it as ``<name>.zip`` and ``<name>_replay_buffer.npz``, their
    update counters in ``state.json["models"]``. Returns its folder."""
    step = int(model.num_timesteps)
    root = Path(out) / CHECKPOINTS
    root.mkdir(parents=True, exist_ok=True)
    final = root / f"step_{step}"
    tmp = root / f".tmp_step_{step}"
    for stale in root.glob(".tmp_step_*"):  # left by a kill during an earlier checkpoint
        shutil.rmtree(stale, ignore_errors=True)
    tmp.mkdir()
    try:
        _write_checkpoint_files(tmp, step, model, worker_states, extra, extra_models)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)  # disk full, a kill: the previous checkpoint stays in force
        named = naming_the_file(exc, final, "the previous checkpoint stays in force")
        if named is exc:
            raise
        raise named from exc
    shutil.rmtree(final, ignore_errors=True)
    tmp.rename(final)
    atomic_write_json(root / LATEST, {"step": step, "dir": final.name})
    kept = sorted((p for p in root.glob("step_*") if p.is_dir()), key=lambda p: int(p.name.split("_")[1]))
    for old in kept[:-KEEP_CHECKPOINTS]:
        shutil.rmtree(old, ignore_errors=True)
    for old in kept[-KEEP_CHECKPOINTS:-1]:
        for buffer in old.glob("*replay_buffer.npz"):
            buffer.unlink(missing_ok=True)
    return final


def _write_checkpoint_files(tmp: Path, step: int, model: Any, worker_states: list[dict[str, np.ndarray]],
                            extra: dict[str, Any], extra_models: Mapping[str, Any] | None) -> None:
    """Every file of checkpoint ``step`` into the folder ``tmp`` (`write_checkpoint`)."""
    model.save(tmp / "model.zip", exclude=SAVE_EXCLUDE)
    if getattr(model, "replay_buffer", None) is not None:
        save_replay_buffer(model.replay_buffer, tmp / "replay_buffer.npz")
    models: dict[str, Any] = {}
    for name, other in (extra_models or {}).items():
        other.save(tmp / f"{name}.zip", exclude=SAVE_EXCLUDE)
        save_replay_buffer(other.replay_buffer, tmp / f"{name}_replay_buffer.npz")
        models[name] = {"n_updates": int(getattr(other, "_n_updates", 0))}
    for i, worker in enumerate(worker_states):
        write_npz(tmp / f"worker_{i}.npz", worker, compressed=True)
    rng_json, rng_arrays = rng_state(model)
    write_npz(tmp / "rng.npz", rng_arrays)
    state = {
        "step": step, "n_updates": int(getattr(model, "_n_updates", 0)),
        "episode_num": int(getattr(model, "_episode_num", 0)), "n_workers": len(worker_states),
        "rng": rng_json, **({"models": models} if models else {}), **extra,
    }
    atomic_write_json(tmp / "state.json", state)


# ---------------------------------------------------------------------------------------------------- reads
class CheckpointError(SealError, ValueError):
    """No usable checkpoint: ``latest.json`` or a file of every candidate checkpoint is damaged."""


def latest_checkpoint(out: Path) -> Path | None:
    """The newest complete checkpoint of the run at ``out``, or None when the run has none yet.

    That is the folder ``latest.json`` names when it and every file of that folder read back; otherwise (a
    damaged ``latest.json``, a truncated ``model.zip`` / ``replay_buffer.npz`` / ...) the newest earlier
    ``step_<N>`` folder that reads back whole, with a warning naming the damaged file. Older checkpoints keep no
    replay buffer (`write_checkpoint`), so an off-policy run whose newest buffer is damaged has no fallback:
    `CheckpointError` names the file and says what to do.
    """
    root = Path(out) / CHECKPOINTS
    pointer = root / LATEST
    folders = sorted((p for p in root.glob("step_*") if p.is_dir() and p.name[5:].isdigit()),
                     key=lambda p: int(p.name[5:]), reverse=True)
    if not pointer.is_file() and not folders:
        return None
    problems: list[str] = []
    named = _pointer_target(pointer, problems)
    candidates = ([named] if named is not None else []) + [f for f in folders if f != named]
    buffers = {b.name for f in folders for b in f.glob("*replay_buffer.npz")}
    for folder in candidates:
        problem = checkpoint_problem(folder, buffers)
        if problem is None:
            if problems:
                logger.warning(f"{'; '.join(problems)}: resuming from the previous complete checkpoint {folder}")
            return folder
        problems.append(f"{pointer} names {folder.name}, but {problem}" if folder == named else problem)
    raise CheckpointError(
        f"{'; '.join(problems) or f'{root}: no checkpoint'}; no complete checkpoint to fall back to: delete "
        f"{root} to restart the run from step 0"
    )


def _pointer_target(pointer: Path, problems: list[str]) -> Path | None:
    """The folder ``latest.json`` names, or None (its problem appended to ``problems``) when it is unreadable."""
    if not pointer.is_file():
        problems.append(f"{pointer} is missing")
        return None
    try:
        latest = json.loads(pointer.read_text())
        name = str(latest["dir"])
    except (OSError, UnicodeDecodeError, ValueError, TypeError, KeyError) as exc:
        problems.append(f"{pointer} is damaged ({type(exc).__name__}: {exc})")
        return None
    if not name.startswith("step_") or "/" in name:
        problems.append(f"{pointer} names {name!r}, not a checkpoint folder")
        return None
    return pointer.parent / name


def check_zip_whole(path: Path) -> None:
    """Raise `zipfile.BadZipFile` (or OSError) unless every member of the zip (``.npz`` or SB3 ``.zip``) at ``path``
    reads back (a truncated or bit-flipped file fails its CRC check)."""
    with zipfile.ZipFile(path) as zf:
        bad = zf.testzip()
        # SB3's zips hold torch archives, zips themselves: a cut one can still open as its inner archive.
        if path.name.endswith(".zip") and "data" not in zf.namelist():
            raise zipfile.BadZipFile("no 'data' entry (a truncated Stable-Baselines3 file)")
    if bad is not None:
        raise zipfile.BadZipFile(f"member {bad} fails its CRC check")


def checkpoint_problem(folder: Path, buffers: Collection[str] = ()) -> str | None:
    """Why the checkpoint ``folder`` cannot be resumed from (naming the file), or None when every file it needs
    reads back: ``state.json``, ``rng.npz``, each ``worker_<i>.npz``, each ``*.zip`` (SB3 model files, with their
    ``data`` entry) and the replay buffers named in ``buffers`` (zip members are read whole: a truncated or
    bit-flipped file fails its CRC check)."""
    path = folder / "state.json"
    try:
        state = json.loads(path.read_text())
        files = ["rng.npz", "model.zip", *(f"worker_{i}.npz" for i in range(int(state["n_workers"])))]
        files += sorted({p.name for p in folder.glob("*.zip")} | set(buffers))
        for name in dict.fromkeys(files):
            path = folder / name
            check_zip_whole(path)
    except (OSError, UnicodeDecodeError, ValueError, TypeError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        reason = "missing" if isinstance(exc, FileNotFoundError) else f"damaged ({type(exc).__name__}: {exc})"
        return f"{path} is {reason}"
    return None


def read_checkpoint_state(folder: Path) -> tuple[dict[str, Any], dict[str, np.ndarray], list[dict[str, np.ndarray]]]:
    """``state.json``, the rng arrays and every worker's state of a checkpoint folder."""
    state = json.loads((folder / "state.json").read_text())
    with np.load(folder / "rng.npz", allow_pickle=False) as z:
        rng_arrays = {k: z[k] for k in z.files}
    workers = []
    for i in range(int(state["n_workers"])):
        path = folder / f"worker_{i}.npz"
        if not path.is_file():
            raise ValueError(f"checkpoint {folder}: {path.name} is missing")
        with np.load(path, allow_pickle=False) as z:
            workers.append({k: z[k] for k in z.files})
    return state, rng_arrays, workers


def load_extra_model(model: Any, checkpoint: Path, name: str, state: Mapping[str, Any]) -> None:
    """Restore an ``extra_models`` entry of `write_checkpoint` (parameters, optimisers, buffer, update count)."""
    load_model_state(model, checkpoint / f"{name}.zip")
    load_replay_buffer(model.replay_buffer, checkpoint / f"{name}_replay_buffer.npz")
    model._n_updates = int(state.get("models", {}).get(name, {}).get("n_updates", 0))


def load_model_state(model: Any, path: Path) -> None:
    """Parameters, optimiser states and saved torch variables (SAC's entropy coefficient) of ``path`` into
    ``model`` (SB3 reads them with ``torch.load(weights_only=True)``; the pickled settings are not read)."""
    from stable_baselines3.common.save_util import load_from_zip_file, recursive_setattr

    model.set_parameters(str(path), exact_match=True, device=model.device)
    _, _, variables = load_from_zip_file(path, device=model.device, load_data=False)
    for name, value in (variables or {}).items():
        recursive_setattr(model, f"{name}.data", value.data)


def truncate_progress(path: Path, step: int) -> None:
    """Keep only the rows of an SB3 ``progress.csv`` logged at or before env step ``step`` (a resumed run
    continues from there; rows of work after the checkpoint were lost with it)."""
    if not path.is_file():
        return
    text = path.read_text()
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        return
    header = rows[0]
    col = header.index("time/total_timesteps") if "time/total_timesteps" in header else None
    lines = text.splitlines(keepends=True)
    if col is None or len(lines) != len(rows):
        return  # not a plain one-line-per-row log: keep it whole rather than guess
    # A row cut short by the kill (fewer fields than the header) goes too.
    kept = [lines[0]] + [line for line, row in zip(lines[1:], rows[1:], strict=True)
                         if len(row) == len(header) and line.endswith("\n")
                         and (row[col] == "" or float(row[col]) <= step)]
    atomic_write_bytes(path, "".join(kept).encode())


def read_done(out: Path) -> dict[str, Any]:
    return json.loads((Path(out) / DONE).read_text())
