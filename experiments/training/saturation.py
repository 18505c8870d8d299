"""Actor saturation in the training log (``actor/edge_share``, ``actor/action_std``).

Why: a TD3 actor ends in tanh, and when its critic keeps asking for more in one direction the pre-activations grow
until the action sits at the edge of the box, where the gradient through tanh vanishes and the policy stops
changing. Measured on the decisive run (session 33): 3 of 28 ReSkill egos took one and the same high-level action in
every state of 20 scenarios, and 6 more nearly so; they scored like the others, so what the pipeline taught them
could not show. These two numbers make that visible while a run trains: on a fixed-size sample of replay-buffer
states, the share of action components at the edge (``|a| > EDGE`` in the policy's [-1, 1] units) and the spread of
the deterministic action over the states (mean over components of the standard deviation; 0 = one action for all).
For the ReSkill ego the model is its high-level agent, so the actions are its skill choices.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

EDGE = 0.99
"""``|action|`` above this counts as at the edge of the [-1, 1] box."""


def actor_saturation(model: Any, n_states: int, rng: np.random.Generator) -> dict[str, float]:
    """``edge_share`` and ``action_std`` of ``model``'s deterministic actions on ``n_states`` states drawn (with
    ``rng``, not SB3's global numpy stream, so training draws the same batches with or without this) from its replay
    buffer; empty for a model without one (PPO) or before anything is stored."""
    import torch

    buffer = getattr(model, "replay_buffer", None)
    if buffer is None or buffer.size() == 0 or not isinstance(buffer.observations, np.ndarray):
        return {}
    rows = rng.integers(0, buffer.size(), n_states)
    envs = rng.integers(0, buffer.n_envs, n_states)
    states = torch.as_tensor(buffer.observations[rows, envs], device=model.device)
    with torch.no_grad():
        actions = model.policy._predict(states, deterministic=True).cpu().numpy().reshape(n_states, -1)
    return {"edge_share": float(np.mean(np.abs(actions) > EDGE)), "action_std": float(actions.std(axis=0).mean())}


class ActorSaturationCallback(BaseCallback):
    """Logs `actor_saturation` every ``every`` env steps as ``actor/edge_share`` and ``actor/action_std``."""

    def __init__(self, every: int = 5_000, n_states: int = 256, seed: int = 0) -> None:
        super().__init__()
        self.every, self.n_states = int(every), int(n_states)
        self.rng = np.random.default_rng(seed)
        self.next_step: float = 0

    def _on_training_start(self) -> None:
        if getattr(self.model, "replay_buffer", None) is None:  # on-policy (PPO): nothing to sample, never look again
            self.next_step = float("inf")

    def _on_step(self) -> bool:
        if self.num_timesteps < self.next_step:
            return True
        stats = actor_saturation(self.model, self.n_states, self.rng)
        if stats:  # else: nothing stored yet, try again next step
            self.next_step = self.num_timesteps + self.every
        for key, value in stats.items():
            self.logger.record(f"actor/{key}", value)
        return True
