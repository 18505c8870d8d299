"""`seal fit skills --demos DIR`: a shared demonstrations file built with other settings is not overwritten by a
fit that needs another version; that fit builds (and later reuses) its own in its output folder."""

from __future__ import annotations

from pathlib import Path

import scenario_factory as sf

from seal.experiments.fitting.skill_data import _find
from seal.models.skills.demonstrations import DemoConfig, roll_out_demonstrations
from seal.models.skills.demos import Demonstrations

NAME = "demos_heuristic.npz"


def _write(folder: Path, cfg: DemoConfig) -> list[str]:
    scenario = sf.lane_change_scenario()
    folder.mkdir(parents=True, exist_ok=True)
    Demonstrations.concat([roll_out_demonstrations(scenario, cfg)], cfg.to_dict()).save(folder / NAME)
    return [scenario.scenario_id]


def test_a_shared_file_with_other_settings_is_left_alone(tmp_path: Path) -> None:
    shared, own = tmp_path / "shared", tmp_path / "own"
    base = DemoConfig(source="heuristic", start_step=0, end_step=30)
    other = DemoConfig(source="heuristic", start_step=0, end_step=30, distraction_rate_hz=0.0)
    ids = _write(shared, base)
    before = (shared / NAME).read_bytes()

    path, demos = _find(NAME, base.to_dict(), ids, shared, own)  # same settings: reused from the shared folder
    assert path == shared / NAME and demos is not None and demos.params == base.to_dict()

    path, demos = _find(NAME, other.to_dict(), ids, shared, own)  # other settings: built in the fit's own folder
    assert path == own / NAME and demos is None
    assert (shared / NAME).read_bytes() == before

    _write(own, other)  # what the build would write there; the next fit with these settings reuses it
    path, demos = _find(NAME, other.to_dict(), ids, shared, own)
    assert path == own / NAME and demos is not None and demos.params == other.to_dict()

    # Without a separate folder of its own (--demos is the output folder) the file is rebuilt in place.
    path, demos = _find(NAME, other.to_dict(), ids, shared, shared)
    assert path == shared / NAME and demos is None
    path, demos = _find(NAME, other.to_dict(), ids, shared, None)
    assert path == shared / NAME and demos is None


def test_a_file_that_recorded_every_setting_is_still_reused(tmp_path: Path) -> None:
    """Before a source's identity held only the settings it uses, every file recorded all of them."""
    from dataclasses import asdict

    cfg = DemoConfig(source="log", start_step=0, end_step=30)
    scenario = sf.lane_change_scenario()
    old_params = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(cfg).items()}
    assert old_params != cfg.to_dict()
    Demonstrations.concat([roll_out_demonstrations(scenario, cfg)], old_params).save(tmp_path / NAME)
    path, demos = _find(NAME, cfg.to_dict(), [scenario.scenario_id], tmp_path, None)
    assert path == tmp_path / NAME and demos is not None
    other = DemoConfig(source="log", start_step=0, end_step=20)  # a setting the source uses still tells them apart
    assert _find(NAME, other.to_dict(), [scenario.scenario_id], tmp_path, None)[1] is None
