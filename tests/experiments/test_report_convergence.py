"""Training convergence in the report: the late slope of the periodic evaluations, its binomial standard error and
the per-pipeline verdict, on hand-built evaluation files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from seal.experiments.report.convergence import convergence_line, convergence_markdown, convergence_rows, late_slope

STEPS = [20_000, 40_000, 60_000, 80_000, 100_000]


def test_late_slope_by_hand() -> None:
    # The last half (3 of 5) of the evaluations: 0.4, 0.5, 0.6 at 60k, 80k, 100k = +10 points per 20k steps.
    slope, se = late_slope(np.array(STEPS), np.array([0.3, 0.3, 0.4, 0.5, 0.6]), np.full(5, 100))
    assert slope == pytest.approx(5.0)
    # weights (x - mean) / sum (x - mean)^2 = [-1, 0, 1] / 40k; var = sum w^2 * p (1 - p) / n with p = 0.5, n = 100
    assert se == pytest.approx(np.sqrt(2 * (1 / 40_000) ** 2 * 0.25 / 100) * 1e6)
    assert np.isnan(late_slope(np.array(STEPS), np.linspace(0.1, 0.5, 5))[1])  # no episode counts: no SE
    assert late_slope(np.array(STEPS[:2]), np.array([0.1, 0.2])) is None  # too few evaluations


def _run(tmp: Path, name: str, pipeline: str, algo: str, success: list[float]) -> dict:
    folder = tmp / name / "eval"
    folder.mkdir(parents=True)
    lines = ["step,episodes,success_rate"] + [f"{s},100,{v}" for s, v in zip(STEPS, success, strict=True)]
    (folder / "evaluations.csv").write_text("\n".join(lines) + "\n")
    return {"run": str(tmp / name), "pipeline": pipeline, "path": str(tmp / name), "config": json.dumps({"algo": algo})}


def test_verdicts_per_pipeline_and_algorithm(tmp_path: Path) -> None:
    rising = [0.2, 0.3, 0.4, 0.5, 0.6]  # +5 points per 10k late, SE ~1.8 a run
    flat = [0.8, 0.8, 0.79, 0.81, 0.8]
    runs = [_run(tmp_path, f"seal-td3-s{i}", "seal", "td3", rising) for i in range(4)]
    runs += [_run(tmp_path, f"seal-reskill-s{i}", "seal", "reskill", flat) for i in range(4)]
    runs += [_run(tmp_path, "noadv-td3-s0", "noadv", "td3", [0.2, 0.3, 0.4, 0.43, 0.46])]  # +1.5 +/- 1.8: unsure
    runs.append({"run": "replay", "pipeline": "replay", "path": None, "config": "{}"})  # no curves: left out
    rows = {r["pipeline"]: r for r in convergence_rows(runs)}
    assert set(rows) == {"seal (td3)", "seal (reskill)", "noadv (td3)"}
    assert rows["seal (td3)"]["verdict"] == "still improving" and rows["seal (td3)"]["late_slope_pts_per_10k"] == 5.0
    assert rows["seal (td3)"]["runs"] == 4 and rows["seal (td3)"]["share_rising"] == 1.0
    assert rows["seal (reskill)"]["verdict"] == "no clear trend" and rows["seal (reskill)"]["final_success"] == 0.8
    assert rows["noadv (td3)"]["verdict"] == "no clear trend"  # 1.5 points, but within 2 SE of one run
    line = convergence_line(list(rows.values()))
    assert line is not None and "seal (td3) (+5.0)" in line and "reskill" not in line
    assert "| seal (td3) | 4 | +5.00 +/- 0.88 |" in convergence_markdown(list(rows.values()))
    falling = [_run(tmp_path, f"cat-td3-s{i}", "cat", "td3", rising[::-1]) for i in range(4)]
    assert convergence_rows(falling)[0]["verdict"] == "falling"
    assert convergence_line([]) is None and "no pipeline" in str(convergence_line(convergence_rows(falling)))
