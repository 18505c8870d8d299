"""`seal fit probes` and `seal eval steering` end to end on a tiny dataset with an untrained prior (small
settings), and their one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import scenario_factory as sf

from seal.cli import main
from seal.core.dataset import Dataset, write_dataset
from seal.models.prior import TrajectoryPrior

FAST_FIT = ["--set", "sae_widths=[8]", "--set", "sae.epochs=5", "--set", "held_out=0.34"]
FAST_EVAL = ["--set", "alphas=[0,1.5]", "--set", "taus_pct=[-100,-50,0,50,100]", "--set", "shift_taus_pct=[-50]",
             "--set", "n_boot=200"]


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("steer_cli")
    scenarios = [sf.mixed_speed_scenario(i, scenario_id=f"h{i}") for i in range(6)]
    write_dataset(root / "ds", scenarios)
    Dataset.open(root / "ds").update_manifest(splits={"train": ["h0", "h1", "h2"], "eval": ["h3", "h4"],
                                                       "hard": ["h5"]})
    TrajectoryPrior.untrained(seed=0).save(root / "prior.pt")
    return root / "prior.pt", root / "ds"


def test_fit_probes_then_eval_steering(setup: tuple[Path, Path], tmp_path: Path, capsys) -> None:
    prior, ds = setup
    out = tmp_path / "probes"
    assert main(["fit", "probes", str(prior), str(ds), "--out", str(out), "--no-progress", "--json", *FAST_FIT]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["data"]["scenes"] == 3 and report["data"]["targets"] == 27
    assert report["label_shares"]["speed"] == [9, 9, 9] and report["label_shares"]["acceleration"] == [9, 9, 9]
    assert set(report["probes"]) == {"input", "layer1", "layer2", "output"}
    assert -1.0 < report["probes"]["output"]["r2_activity"]["test"] <= 1.0
    assert {"risk_activity@output", "risk_proximity@layer1", "speed@output", "acceleration@layer2",
            "speed_sae8@output", "acceleration_sae8@input"} <= set(report["vectors"])
    assert "direction@output" not in report["vectors"]  # nobody turns: no control vector without both classes
    assert (out / "steering.pt").is_file() and (out / "config.yaml").is_file()

    ev = tmp_path / "eval"
    assert main(["eval", "steering", str(prior), str(out), str(ds), "--out", str(ev), "--no-progress", "--json",
                 "--shift-dataset", str(ds), "--shift-split", "hard", *FAST_EVAL]) == 0
    r = json.loads(capsys.readouterr().out)
    first = next(iter(r["risk"].values()))
    assert first["alphas"] == [0.0, 1.5] and first["structured"]["activity"][0] == first["random"]["activity"][0]
    assert 0.0 <= first["plausible_structured"] <= 1.0 and first["margin"]["n"] > 0
    speed = r["speed"]["speed@output"]
    assert speed["change"][speed["taus_pct"].index(0.0)] == 0.0
    rows = r["domain_shift"]["synthetic"]["rows"]
    assert rows[0]["vector"] is None and {row["tau_from"] for row in rows} >= {"unsteered", "calibrated", "fixed"}
    unshifted = r["domain_shift"]["unshifted"][0]
    assert unshifted["targets"] == rows[0]["targets"] and 0 < unshifted["min_ade"] != rows[0]["min_ade"] > 0
    assert r["domain_shift"]["dataset"]["targets"] > 0
    for name in ("report.json", "risk_vs_alpha.png", "plausibility_vs_alpha.png", "speed_calibration.png"):
        assert (ev / name).is_file(), name


@pytest.mark.parametrize("argv, message", [
    (["fit", "probes", "missing.pt", "DS", "--out", "O"], "missing.pt not found"),
    (["fit", "probes", "PRIOR", "DS", "--out", "O", "--set", "risk_quantile=0.9"], "risk_quantile"),
    (["fit", "probes", "PRIOR", "DS", "--out", "O", "--set", "nope=1"], "nope"),
    (["eval", "steering", "PRIOR", "missing_dir", "DS", "--out", "O"], "steering file"),
    (["eval", "steering", "PRIOR", "PRIOR", "DS", "--out", "O"], "not written by seal fit probes"),
    (["eval", "steering", "PRIOR", "PRIOR", "DS", "--out", "O", "--set", "shift_factor=2"], "shift_factor"),
])
def test_bad_input_is_one_line_exit_2(setup: tuple[Path, Path], argv: list[str], message: str, capsys) -> None:
    prior, ds = setup
    argv = [str(prior) if a == "PRIOR" else str(ds) if a == "DS" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
