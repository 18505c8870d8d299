"""Every preset of ``experiments/configs/`` resolves to the same effective values as before the typed configs.

``data/resolved_presets.json`` was recorded from the dict-based configs (``DEFAULTS`` + ``resolve_config`` /
``load_train_config`` at commit ac931ba) for each preset, with and without command-line style overrides; the
dataclass configs must give the same plain data. Changed since: the standard and paper presets train with
``torch_threads: 2`` (issue 17's throughput); the objective's ``seal`` label behaviour uses skill noise 0.5, as the
SEAL generator (`seal.envs.skill_behavior.SKILL_NOISE_SCALE`, issue 16)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from seal.core.config import to_dict
from seal.experiments.fitting import behavior, goose, objective, skills
from seal.experiments.training.config import PIPELINES, load_train_config

RECORDED = json.loads((Path(__file__).parent / "data" / "resolved_presets.json").read_text())
TRAIN_CLI = {"pipeline": "seal", "seed": 3, "dataset": "d", "total_timesteps": 800, "n_envs": 1,
             "pipelines.seal.kwargs.prior": "p.pt", "hyperparams.td3.learning_starts": 5}


def _resolved(key: str) -> dict[str, Any]:
    kind, preset, *rest = key.split("/")
    if kind == "train":
        if rest == ["cli"]:
            return load_train_config(preset, TRAIN_CLI)
        return load_train_config(preset, {"pipeline": rest[0], "algo": rest[1]})
    if kind == "goose":
        extra = dict(algo="td3", total_steps=10, seed=2, split="s", limit=3, eval_split="e", eval_limit=4)
        return to_dict(goose.resolve_config(preset, **(extra if rest else {})))
    if kind == "behavior":
        cli = dict(split="s", limit=5, eval_split="e", eval_limit=3, seeds=[4], threads=1, max_samples=50)
        return to_dict(behavior.resolve_config(preset, **(cli if rest else {})))
    if kind == "skills":
        return to_dict(skills.resolve_config(preset, **(dict(split="s", limit=3, seed=2, workers=1) if rest else {})))
    extra = dict(prior="p.pt", eval_split="e", eval_limit=3, workers=1, seed=4, split="s", limit=5)
    return to_dict(objective.resolve_config(preset, **(extra if rest else {"candidates": "lanes"})))


def test_every_recorded_case_is_covered() -> None:
    configs = Path(__file__).resolve().parents[2] / "experiments" / "configs"
    # quick_ablations is newer than the recording (tests/experiments/test_run_pipeline.py checks it resolves), as
    # are the background presets (tests/experiments/test_background_eval.py) and decisive (test_decisive.py).
    presets = {p.stem for p in configs.glob("*.yaml")} - {"eval_generators", "eval_seal_ablations", "prior_default",
                                                          "quick_ablations", "background_quick", "background_standard",
                                                          "decisive"}
    recorded = {k.split("/")[1] if k.startswith("train/") else f"{k.split('/')[0]}_{k.split('/')[1]}"
                for k in RECORDED}
    assert presets == recorded  # a new preset file needs a recorded case
    assert {k.split("/")[2] for k in RECORDED if k.startswith("train/") and k.count("/") == 3} == set(PIPELINES)


@pytest.mark.parametrize("key", sorted(RECORDED))
def test_preset_resolves_to_recorded_values(key: str) -> None:
    resolved = _resolved(key)
    if key.startswith("train/"):
        # Added after the recording (issue 17): off-policy updates overlap env stepping by default.
        assert resolved.pop("overlap_updates") is True
        # Added after the recording (issue 26): the time-aware ego is opt-in.
        assert resolved.pop("deadline_obs") is False
        # Added after the recording (issue 26): revisits of the last scenario are opt-in.
        assert resolved.pop("revisit_prob") == 0.0
        # Added after the recording (issue 25): SB3 policy_kwargs besides net_arch, none by default.
        if "policy_kwargs" in resolved["hyperparams"]:
            assert resolved["hyperparams"].pop("policy_kwargs") == {}
    if key.startswith("goose/"):
        # Added after the recording: checkpoints of a running fit (they change nothing that is learnt).
        assert resolved.pop("checkpoint_every") == 1000
    if key.startswith("objective/"):
        # Added after the recording (issue 16, session 43): the seal label behaviour's hand-over to benign skills.
        assert resolved.pop("adversarial_steps") == 10
    assert resolved == RECORDED[key]


@pytest.mark.parametrize("preset,overrides", [
    ("standard", TRAIN_CLI),
    ("decisive", {"pipeline": "noadv", "algo": "td3", "dataset": "d"}),
    ("decisive", {"pipeline": "seal", "algo": "reskill", "dataset": "d", "pipelines.seal.kwargs.prior": "p.pt",
                  "hyperparams.reskill.skills": "s"}),
])
def test_a_run_folder_trains_again_as_recorded(tmp_path: Path, preset: str, overrides: dict[str, Any]) -> None:
    """`seal train --config RUN` (a run folder or its config.yaml): the recorded, resolved config resolves to itself,
    preset name included, and --set / options change it as they change a preset."""
    import yaml

    resolved = load_train_config(preset, overrides)
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(yaml.safe_dump(resolved, sort_keys=True))
    assert load_train_config(run) == resolved
    assert load_train_config(run / "config.yaml") == resolved
    again = load_train_config(run, {"seed": 9}, sets=["deadline_obs=false"])
    assert again == {**resolved, "seed": 9, "deadline_obs": False}


@pytest.mark.parametrize("name", ["eval_generators", "eval_seal_ablations"])
def test_generator_entries_of_the_eval_configs_are_options_of_their_generators(name: str) -> None:
    """Each entry of a `seal eval generators` config names options its generator's constructor takes (a typo such
    as ``objective_head`` fails here, not after the first minutes of an evaluation)."""
    import inspect

    import yaml

    from seal.adversaries.base import generator_class
    from seal.experiments.evaluation.protocol import generator_name

    path = Path(__file__).resolve().parents[2] / "experiments" / "configs" / f"{name}.yaml"
    entries = yaml.safe_load(path.read_text())["generators"]
    assert entries
    for label, kwargs in entries.items():
        params = inspect.signature(generator_class(generator_name(label, kwargs or {}))).parameters
        assert set(kwargs or {}) - {"generator"} <= set(params), (label, kwargs)
