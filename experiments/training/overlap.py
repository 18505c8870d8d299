"""Gradient updates that overlap env stepping (``seal train``, off-policy algorithms).

SB3's off-policy loop alternates: the env workers step (the learner waits), then ``train()`` runs its gradient
steps (the workers wait). On a 2-core machine the workers' simulation and the learner's updates can run at the
same time instead. `OverlapVecEnv` sends the actions to the workers (``step_async``), runs the jobs queued since
the last step (the deferred ``train()`` calls) while they simulate, and only then collects the results
(``step_wait``). `overlapped` turns an SB3 algorithm class into one whose ``train()`` queues itself there.

What changes: each training call's gradient steps run one vec-step later than in SB3's loop (the next action is
chosen by the weights before them, and their batches are sampled from a buffer one vec-step shorter). What does
not: the number of gradient steps, their batch size and the data they are sampled from, i.e. the algorithm's
update-to-data ratio. `OverlapVecEnv.flush` runs pending jobs at once (before a checkpoint, at the end of learning),
so a saved model holds every update of the steps it has seen.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper


class OverlapVecEnv(VecEnvWrapper):
    """A vec env that runs queued jobs between sending the actions to its workers and collecting their results
    (see the module docstring). Jobs must not talk to the env workers (no ``env_method`` while they step)."""

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv)
        self.jobs: list[Callable[[], Any]] = []
        self.jobs_run = 0
        """Jobs run so far (inside a step or by `flush`)."""

    def defer(self, job: Callable[[], Any]) -> None:
        """Run ``job`` during the next step (or at the next `flush`)."""
        self.jobs.append(job)

    def flush(self) -> None:
        """Run every pending job now, in the order they were queued."""
        jobs, self.jobs = self.jobs, []
        for job in jobs:
            job()
            self.jobs_run += 1

    def reset(self) -> Any:
        return self.venv.reset()

    def step_wait(self) -> Any:
        self.flush()  # the workers are simulating the actions step_async sent
        return self.venv.step_wait()


def find_overlap_env(env: Any) -> OverlapVecEnv | None:
    """The `OverlapVecEnv` in a chain of vec-env wrappers, or None."""
    while env is not None:
        if isinstance(env, OverlapVecEnv):
            return env
        env = getattr(env, "venv", None)
    return None


_CLASSES: dict[Any, Any] = {}


def overlapped(algo: Any) -> Any:
    """Subclass of the SB3 off-policy class ``algo`` whose ``train()`` is deferred to the `OverlapVecEnv` found in
    its env (runs at once when there is none)."""
    if algo in _CLASSES:
        return _CLASSES[algo]

    def train(self: Any, gradient_steps: int, batch_size: int = 100) -> None:
        overlap = find_overlap_env(self.env)
        if overlap is None:
            algo.train(self, gradient_steps, batch_size)
            return
        overlap.defer(lambda: algo.train(self, gradient_steps, batch_size))

    cls = type(f"Overlapped{algo.__name__}", (algo,), {"train": train, "__doc__": overlapped.__doc__})
    _CLASSES[algo] = cls
    return cls
