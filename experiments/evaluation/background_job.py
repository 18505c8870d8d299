"""The ``seal eval background`` job: open loop, intent control and closed loop (`background`,
`background_closed`) on held-out scenarios; ``OUT/background_eval.json`` and ``OUT/background_eval.png``."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from seal.core.atomic import atomic_write_json
from seal.core.dataset import load_split
from seal.core.errors import SealError
from seal.envs.background import IDMBackground
from seal.experiments.evaluation.background import build_controllers, intent_metrics, open_loop_metrics, plot_background
from seal.experiments.evaluation.background_closed import closed_loop_metrics, rear_end_change

PARTS = ("open", "intent", "closed")
OPEN_LOOP_KINDS = ("constant_velocity", "idm", "rapid")
CLOSED_LOOP_KINDS = ("replay", "idm", "rapid")


def run_background_eval(
    dataset: str | Path, model: str | Path | None, out: str | Path | None, *, split: str = "eval",
    limit: int | None = None, parts: Sequence[str] = PARTS, egos: Sequence[str] = ("heuristic",),
    closed_dataset: str | Path | None = None, closed_limit: int | None = None, seed: int = 0,
    guidance: dict[str, float] | None = None, ddim_steps: int = 5, progress: bool = True,
) -> dict[str, Any]:
    """Evaluate the background kinds (module docstring); every option is checked before anything runs."""
    from tqdm import tqdm

    from seal.models.rapid import load_rapid

    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        raise SealError(f"--parts: unknown part(s) {unknown}; use {', '.join(PARTS)}")
    rapid = None if model is None else load_rapid(model, guidance, ddim_steps)
    if rapid is None and "intent" in parts:
        raise SealError("--parts intent needs --model (a seal fit background model file)")
    scenarios = load_split(dataset, split, limit, what="held-out")
    closed = load_split(closed_dataset or dataset, split, closed_limit, what="closed-loop") if "closed" in parts \
        else []
    report: dict[str, Any] = {"dataset": str(dataset), "split": split, "scenarios": len(scenarios), "seed": seed,
                              "model": None if model is None else str(model),
                              "guidance": None if rapid is None else vars(rapid.guidance), "ddim_steps": ddim_steps}
    start = time.perf_counter()
    if "open" in parts:
        kinds = [k for k in OPEN_LOOP_KINDS if k != "rapid" or rapid is not None]
        with tqdm(total=len(scenarios), desc="open loop", disable=not progress) as bar:
            report["open_loop"] = open_loop_metrics(scenarios, build_controllers(kinds, rapid), seed, bar)
    if "intent" in parts:
        with tqdm(total=2 * len(scenarios), desc="intent control", disable=not progress) as bar:
            report["intent"] = intent_metrics(scenarios, rapid, seed, progress=bar)
            # the same commanded speeds as desired speeds of the env's IDM (`background` module docstring)
            report["intent_idm_reference"] = intent_metrics(scenarios, IDMBackground(), seed, heading=False,
                                                            progress=bar)
    if "closed" in parts:
        kinds = [k for k in CLOSED_LOOP_KINDS if k != "rapid" or rapid is not None]
        report["closed_loop_dataset"] = str(closed_dataset or dataset)
        with tqdm(total=len(closed) * len(kinds) * len(egos), desc="closed loop", disable=not progress) as bar:
            report["closed_loop"] = closed_loop_metrics(closed, egos, kinds, rapid, seed, bar)
        report["rear_end_rate_change_vs_replay"] = rear_end_change(report["closed_loop"])
    report["seconds"] = round(time.perf_counter() - start, 1)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "background_eval.json", report)
        if "open_loop" in report:
            plot_background(report, out / "background_eval.png")
    return report
