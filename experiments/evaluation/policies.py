"""Evaluate a Python policy with the `seal eval runs` protocol, from your own script.

    from seal.experiments.evaluation.policies import evaluate_policy

    evaluate_policy(lambda obs: np.array([0.0, 0.2]), "my-policy", "data/pool", settings="normal,hard,rule",
                    store="results.sqlite")

The policy is anything `seal.experiments.training.egos.as_ego` adapts: a callable ``observation [100] -> action
[2]`` (normalised ``[steering, acceleration]``), an object with SB3's ``predict`` (a model you loaded yourself, a
`HeuristicDriver`), or an object with ``reset(scenario)`` and ``act(observation, step)``. It plays in this
process (it is not pickled into workers), one row per scenario and setting goes into the results store under
``name`` (the pipeline ``seal compare`` shows), exactly as for a trained run.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.experiments.backends import InlineBackend
from seal.experiments.evaluation.parallel import evaluate_runs
from seal.experiments.training.egos import register_policy


def evaluate_policy(
    policy: Any, name: str, dataset: str | Path, settings: str | Sequence[str] = "normal,hard",
    store: str | Path = "results.sqlite", config: Mapping[str, Any] | None = None, replay_ego: bool = False,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Evaluate ``policy`` as ego ``name`` on ``settings`` of ``dataset`` (``normal``, ``hard``, a generator name,
    ``real:DIR``) into the results store ``store``; returns ``[{"run": name, "written": {setting: rows}}]`` (plus
    the Replay ego's when ``replay_ego``). ``config``: `seal.experiments.evaluation.evaluate.EvalRunsConfig` keys
    (generator kwargs, ``k``, ``limit``, ``seed``, ``env``); scenarios already in the store are skipped."""
    from seal.experiments.evaluation.evaluate import resolve_eval_config

    if not name or name in ("replay", "heuristic"):
        raise ValueError(f"evaluate_policy: name {name!r} must be non-empty and not a built-in ego")
    register_policy(name, policy)
    resolved = resolve_eval_config(**{k: v for k, v in dict(config or {}).items() if k != "generators"})
    for generator, kwargs in dict((config or {}).get("generators") or {}).items():
        resolved["generators"][str(generator)] = dict(kwargs or {})
    return evaluate_runs([name], settings, str(store), dataset=dataset, config=resolved, replay_ego=replay_ego,
                         progress=progress, backend=InlineBackend())
