"""SB3 callbacks and logging of ``seal train``: episode outcome rates, checkpoints, periodic evaluation on the
Normal eval split, a progress bar, and a CSV log that continues a resumed run's ``progress.csv``."""

from __future__ import annotations

import csv
import io
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import CSVOutputFormat

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.outcome import OUTCOMES, Outcome
from seal.core.scenario import Scenario
from seal.experiments.training.numpy_actor import deterministic_actor


class ResumableCSVOutputFormat(CSVOutputFormat):
    """SB3's CSV log, but an existing file's rows are kept (SB3's opens it with ``"w+"``, emptying it)."""

    def __init__(self, filename: str) -> None:
        path = Path(filename)
        old = path.read_text() if path.is_file() else ""
        super().__init__(filename)
        if old.strip():
            self.file.write(old if old.endswith("\n") else old + "\n")
            self.file.flush()
            self.keys = next(csv.reader(io.StringIO(old)))


class EpisodeStatsCallback(BaseCallback):
    """Outcome rates of the last ``window`` training episodes, logged as ``episode/*`` (success; clean success:
    success without touching anyone, the evaluation's success; crash: the ego touched another agent at any step,
    out-of-road, timeout, route completion, share perturbed by the generator,
    and of the perturbed ones the share whose generator aimed at the logged ego because the scenario's queue held
    no roll-out of the ego yet: ``log_target_share``, see ``train.revisit_prob``) and ``generator/time_ms`` (mean
    generation time of the perturbed ones). ``totals`` counts every episode of
    this session: by final outcome (``crash`` only counts episodes a crash ended, never with
    ``terminate_on_crash: false``) and ``crashed``, the episodes in which the ego touched another agent at any
    step (what ``episode/crash_rate`` is a rate of)."""

    def __init__(self, window: int = 100) -> None:
        super().__init__()
        self.recent: deque[dict[str, Any]] = deque(maxlen=window)
        self.totals: dict[str, float] = {"episodes": 0, "generation_s": 0.0, "perturbed": 0, "crashed": 0,
                                         **{o: 0 for o in OUTCOMES}}

    def _on_step(self) -> bool:
        for info, done in zip(self.locals["infos"], self.locals["dones"], strict=True):
            rollout = info.get("rollout") if done else None
            if rollout is None:
                continue
            adv = info.get("episode_adversary") or {}
            record = {
                "outcome": rollout.outcome, "crashed": rollout.crashed, "completion": rollout.route_completion,
                "perturbed": bool(adv.get("perturbed", False)),
                "generation_s": float(adv.get("generation_time_s") or 0.0),
                "targets_log": bool(adv.get("targets_log", False)),
            }
            self.recent.append(record)
            t = self.totals
            t["episodes"] += 1
            t[rollout.outcome] = t.get(rollout.outcome, 0) + 1
            t["perturbed"] += record["perturbed"]
            t["crashed"] += bool(record["crashed"])
            t["generation_s"] += record["generation_s"]
            self._record()
        return True

    def rates(self) -> dict[str, float]:
        r = list(self.recent)
        if not r:
            return {}
        gen = [e["generation_s"] for e in r if e["perturbed"]]
        aimed_at_log = [e["targets_log"] for e in r if e["perturbed"]]
        return {
            "success_rate": float(np.mean([e["outcome"] == Outcome.SUCCESS for e in r])),
            # What the evaluation (crash ends the episode) would call a success: with ``terminate_on_crash: false``
            # an ego that touched someone and drove on to the goal still ends in SUCCESS above.
            "clean_success_rate": float(np.mean([e["outcome"] == Outcome.SUCCESS and not e["crashed"] for e in r])),
            "crash_rate": float(np.mean([e["crashed"] for e in r])),
            "out_of_road_rate": float(np.mean([e["outcome"] == Outcome.OUT_OF_ROAD for e in r])),
            "timeout_rate": float(np.mean([e["outcome"] == Outcome.TIMEOUT for e in r])),
            "route_completion": float(np.mean([e["completion"] for e in r])),
            "perturbed_share": float(np.mean([e["perturbed"] for e in r])),
            "log_target_share": float(np.mean(aimed_at_log)) if aimed_at_log else 0.0,
            "generation_ms": 1e3 * float(np.mean(gen)) if gen else 0.0,
        }

    def _record(self) -> None:
        rates = self.rates()
        for key, value in rates.items():
            self.logger.record("generator/time_ms" if key == "generation_ms" else f"episode/{key}", value)
        self.logger.record("generator/total_s", self.totals["generation_s"])


class CheckpointCallback(BaseCallback):
    """Every ``every`` env steps (at the start of a collection, i.e. after the previous training update, so the
    model, its replay buffer and the step count agree) calls ``save(model)``; 0 = never."""

    def __init__(self, every: int, total_steps: int, save: Callable[[Any], None]) -> None:
        super().__init__()
        self.every, self.total_steps, self.save = int(every), int(total_steps), save
        self.next_step = 0

    def _on_training_start(self) -> None:
        if self.every:
            self.next_step = (self.num_timesteps // self.every + 1) * self.every

    def _on_rollout_start(self) -> None:
        if self.every and self.next_step <= self.num_timesteps < self.total_steps:
            self.save(self.model)
            self.next_step = (self.num_timesteps // self.every + 1) * self.every

    def _on_step(self) -> bool:
        return True


def evaluate_policy_on(model: Any, env: Any, scenarios: Sequence[Scenario]) -> list[dict[str, Any]]:
    """One deterministic episode of ``model`` per scenario in ``env`` (a `ScenarioEnv`, logged adversary):
    ``[{scenario_id, outcome, crashed, route_completion, return, steps}]``."""
    rows = []
    # The weights do not change during the evaluation: a TD3 actor acts through its numpy copy (~10x cheaper).
    fast = deterministic_actor(model)
    for i, scenario in enumerate(scenarios):
        obs, _ = env.reset(seed=i, options={"scenario_id": scenario.scenario_id})
        done, start = False, True
        info: dict[str, Any] = {}
        while not done:
            # episode_start: a stateful policy (the ReSkill ego's skill schedule) restarts with the episode.
            if fast is not None:
                action = fast(obs)
            else:
                action, _ = model.predict(obs, episode_start=np.array([start]), deterministic=True)
            start = False
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        r = info["rollout"]
        rows.append({"scenario_id": scenario.scenario_id, "outcome": r.outcome, "crashed": r.crashed,
                     "route_completion": round(r.route_completion, 4), "return": round(r.episode_return, 3),
                     "steps": r.n_steps})
    return rows


def summarize_eval(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    return {
        "success_rate": float(np.mean([r["outcome"] == Outcome.SUCCESS for r in rows])),
        "crash_rate": float(np.mean([r["crashed"] for r in rows])),
        "out_of_road_rate": float(np.mean([r["outcome"] == Outcome.OUT_OF_ROAD for r in rows])),
        "route_completion": float(np.mean([r["route_completion"] for r in rows])),
        "mean_return": float(np.mean([r["return"] for r in rows])),
    }


class EvalCallback(BaseCallback):
    """Every ``every`` env steps and at the end of training: `evaluate_policy_on` the eval scenarios; appends a
    row to ``eval/evaluations.csv``, writes ``eval/step_<N>.json`` and logs ``eval/*``."""

    def __init__(self, every: int, folder: Path, make_env: Callable[[], Any], scenarios: Sequence[Scenario],
                 make_policy: Callable[[Any], Any] | None = None) -> None:
        super().__init__()
        self.every, self.folder, self.make_env, self.scenarios = int(every), Path(folder), make_env, list(scenarios)
        self.make_policy = make_policy
        """The model -> what plays the evaluation (None: the model itself; ReSkill: its two-level policy)."""
        self.env: Any = None
        self.next_step = 0
        self.last_step = -1
        self.last: dict[str, float] = {}

    def _on_training_start(self) -> None:
        self.next_step = (self.num_timesteps // self.every + 1) * self.every if self.every else 0

    def _on_step(self) -> bool:
        if self.every and self.num_timesteps >= self.next_step:
            self.evaluate()
            self.next_step = (self.num_timesteps // self.every + 1) * self.every
        return True

    def evaluate(self) -> dict[str, float]:
        if self.env is None:
            self.env = self.make_env()
        start = time.perf_counter()
        policy = self.make_policy(self.model) if self.make_policy is not None else self.model
        rows = evaluate_policy_on(policy, self.env, self.scenarios)
        summary = {"step": int(self.num_timesteps), "episodes": len(rows), **summarize_eval(rows),
                   "eval_s": round(time.perf_counter() - start, 2)}
        atomic_write_json(self.folder / f"step_{self.num_timesteps}.json", {"summary": summary, "episodes": rows})
        append_csv_row(self.folder / "evaluations.csv", summary)
        for key, value in summary.items():
            if key not in ("step", "episodes"):
                self.logger.record(f"eval/{key}", value)
        self.logger.record("time/total_timesteps", self.num_timesteps)
        self.logger.dump(self.num_timesteps)  # its own row: SB3 dumps only at episode ends
        self.last, self.last_step = summary, int(self.num_timesteps)
        return summary

    def _on_training_end(self) -> None:
        if self.every and self.last_step != self.num_timesteps:
            self.evaluate()
        if self.env is not None:
            self.env.close()


def append_csv_row(path: Path, row: dict[str, Any]) -> None:
    """Append ``row`` to a CSV file (header from the first row; the file is rewritten atomically)."""
    old = path.read_text() if path.is_file() else ""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(row))
    if not old:
        writer.writeheader()
    writer.writerow(row)
    atomic_write_bytes(path, (old + buf.getvalue()).encode())


def truncate_eval(folder: Path, step: int) -> None:
    """Drop evaluations made after env step ``step`` (a resumed run redoes them)."""
    for path in folder.glob("step_*.json"):
        if int(path.stem.split("_")[1]) > step:
            path.unlink()
    csv_path = folder / "evaluations.csv"
    if csv_path.is_file():
        rows = list(csv.DictReader(io.StringIO(csv_path.read_text())))
        csv_path.unlink()
        for row in rows:
            if int(row["step"]) <= step:
                append_csv_row(csv_path, row)


class ProgressCallback(BaseCallback):
    """tqdm bar over the run's env steps (starting at the resumed step), showing p(t) and recent outcome rates."""

    def __init__(self, total_steps: int, stats: EpisodeStatsCallback, curriculum: Any, enabled: bool = True) -> None:
        super().__init__()
        self.total_steps, self.stats, self.curriculum, self.enabled = int(total_steps), stats, curriculum, enabled
        self.bar: Any = None
        self._shown = 0
        self._last_post = 0.0

    def _on_training_start(self) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=self.total_steps, initial=self.num_timesteps, unit="step", desc="train",
                        disable=not self.enabled, dynamic_ncols=True, smoothing=0.05)
        self._shown = self.num_timesteps

    def _on_step(self) -> bool:
        self.bar.update(self.num_timesteps - self._shown)
        self._shown = self.num_timesteps
        now = time.monotonic()
        if now - self._last_post > 2.0:
            r = self.stats.rates()
            post = {"p": f"{self.curriculum.p or 0.0:.2f}"}
            if r:
                post.update(succ=f"{r['success_rate']:.2f}", crash=f"{r['crash_rate']:.2f}")
            self.bar.set_postfix(post, refresh=False)
            self._last_post = now
        return True

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.close()


class RestoreCallback(BaseCallback):
    """At training start (after SB3's own env reset): put back a checkpoint's worker states (roll-out queues,
    env rngs) and the global / action-space rng states, then reset the envs again so that the first episodes are
    drawn from the restored rngs and queues."""

    def __init__(self, workers: Sequence[dict[str, np.ndarray]], rng_json: dict[str, Any],
                 rng_arrays: dict[str, np.ndarray]) -> None:
        super().__init__()
        self.workers, self.rng_json, self.rng_arrays = list(workers), rng_json, rng_arrays

    def _on_training_start(self) -> None:
        from seal.experiments.training.state import set_rng_state

        env = self.training_env
        for i, state in enumerate(self.workers):
            env.env_method("set_state", state, f"checkpoint worker_{i}.npz", indices=[i])
        set_rng_state(self.model, self.rng_json, self.rng_arrays)
        self.model._last_obs = env.reset()  # type: ignore[assignment]  # SB3 types reset()'s tuple case too
        self.model._last_episode_starts = np.ones((env.num_envs,), dtype=bool)

    def _on_step(self) -> bool:
        return True
