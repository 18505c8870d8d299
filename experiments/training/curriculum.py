"""CAT's training curriculum (DESIGN section 4): the share of training episodes the generator perturbs grows
linearly with the training step, p(t) = min(slope * t / T, cap) (CAT: slope 1.8, cap 0.9, i.e. 0.9 from half
of training on), and is pushed to every env worker by `CurriculumCallback`.

``warmup`` (a share of T, default 0) adds SEAL's non-reactive start (thesis 6.4, Fig. 6.5 "w/o non-reactive
start"): for t < warmup T nothing is perturbed (the ego first learns on the logged, non-reactive traffic) and the
ramp starts there, p(t) = min(slope * (t / T - warmup), cap). "Without curriculum" is a slope so steep that p is at
its cap as soon as the warm-up ends."""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback

SLOPE = 1.8
CAP = 0.9


def perturb_probability(step: int, total_steps: int, slope: float = SLOPE, cap: float = CAP,
                        warmup: float = 0.0) -> float:
    """p(t) = min(slope * (t / T - warmup), cap) for env step ``t`` of ``T``, 0 before ``warmup * T`` (clipped to
    [0, cap] outside [0, T])."""
    if total_steps <= 0:
        raise ValueError(f"total_steps must be positive, got {total_steps}")
    if slope < 0 or not 0.0 <= cap <= 1.0 or not 0.0 <= warmup < 1.0:
        raise ValueError(f"curriculum: need slope >= 0, cap in [0, 1] and warmup in [0, 1), got slope {slope}, "
                         f"cap {cap}, warmup {warmup}")
    return float(min(max(slope * (step / total_steps - warmup), 0.0), cap))


class CurriculumCallback(BaseCallback):
    """Sets ``perturb_prob`` in every env (``env_method("set_perturb_prob", p)``) from the model's env step count.

    Every env worker is updated when p has moved by at least ``resolution`` since the last update (and at the
    start of training), so the inter-process calls stay rare (at most ``cap / resolution`` + 1 of them) while
    p lags the exact schedule by less than ``resolution``. The value in force is logged as ``curriculum/p``.

    Args:
        total_steps: T, the run's total env steps (not the steps left after a resume).
        slope, cap, warmup: the schedule (`perturb_probability`).
        resolution: smallest change of p sent to the workers.
        log: log ``curriculum/p`` (False for a pipeline without a generator, where p changes nothing).
    """

    def __init__(self, total_steps: int, slope: float = SLOPE, cap: float = CAP, resolution: float = 0.005,
                 warmup: float = 0.0, log: bool = True) -> None:
        super().__init__()
        self.log = bool(log)
        self.total_steps = int(total_steps)
        self.slope, self.cap, self.resolution = float(slope), float(cap), float(resolution)
        self.warmup = float(warmup)
        self.p: float | None = None

    def target(self) -> float:
        return perturb_probability(self.num_timesteps, self.total_steps, self.slope, self.cap, self.warmup)

    def _push(self, p: float) -> None:
        self.training_env.env_method("set_perturb_prob", p)
        self.p = p

    def _on_training_start(self) -> None:
        self._push(self.target())

    def _on_step(self) -> bool:
        p = self.target()
        if self.p is None or abs(p - self.p) >= self.resolution or (p == self.cap and self.p != self.cap):
            self._push(p)
        if self.log:
            self.logger.record("curriculum/p", self.p)
        return True
