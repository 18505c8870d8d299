"""`seal run` checks its whole plan before the first step: bad values in any section fail at once, naming the
section and key, and nothing is written."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from seal.experiments.pipeline.run import run_pipeline

GOOD = {
    "data": {"generate": {"n": 3, "seed": 0}, "split": {"n_train": 1, "n_eval": 2, "n_hard": 1}},
    "fit": {"prior": {"epochs": 1, "no_progress": True}},
    "generators": {"cat": {"prior": "${fit.prior}"}},
    "pipelines": ["noadv", "cat"],
    "seeds": [0],
    "eval": {"settings": ["normal", "hard", "cat"], "k": 2, "limit": 2},
    "report": {"plots": False},
    "train": {"algo": "td3", "total_timesteps": 100},
}


def _nested(base: dict, dotted: str, value: object) -> dict:
    out = yaml.safe_load(yaml.safe_dump(base))
    node = out
    *path, last = dotted.split(".")
    for key in path:
        node = node.setdefault(key, {})
    node[last] = value
    return out


@pytest.mark.parametrize(("key", "value", "message"), [
    ("eval.limit", "ten", r"eval: .*limit"),
    ("eval.settings", ["normal", "sideways"], r"eval: .*unknown setting 'sideways'"),
    ("eval.settings", ["normal", "real:/no/such/dir"], r"eval: .*/no/such/dir"),
    ("eval.replay_ego", "yes", r"eval.replay_ego must be true or false"),
    ("eval.egos", "heuristic", r"eval.egos must be a list of ego names or model paths"),
    ("eval.egos", ["heuristic", "/no/such/run"], r"eval.egos: /no/such/run: not 'replay', 'heuristic'"),
    ("pipelines", ["noadv", "brake"], r"pipelines: unknown pipeline 'brake'"),
    ("seeds", [0, -1], r"seeds: every seed must be a non-negative integer"),
    ("data.path", "/no/such/dataset", r"data.path: .*/no/such/dataset"),
    ("data.generate.n", 0, r"data.generate: --n"),
    ("data.split.n_hard", "x", r"data.split.n_hard must be an integer"),
    ("data.split.hard_by", "focal", r"data.split: --hard-by"),
    ("fit.prior.epochs", -1, r"fit.prior.epochs must be a non-negative integer"),
    ("fit.prior.max_minutes", "long", r"fit.prior.max_minutes must be a positive number"),
    ("fit.prior.path", "/no/such/prior.pt", r"fit.prior.path: /no/such/prior.pt does not exist"),
    ("fit.prior.model", "oracle", r"fit: unknown fit.prior.model 'oracle'"),
    ("fit.prior.model", 3, r"fit.prior.model must be the name of a fitted model kind"),
    ("fit.prior.demos", "/d", r"fit.prior: unknown option\(s\) \['demos'\]"),
    ("fit.prior.set", ["epochs=2"], r"fit.prior: unknown option\(s\) \[.set.\]"),
    ("train.hyperparams", {"td3": {"learning_rate": "fast"}}, r"train \(noadv, seed 0\): .*learning_rate"),
    ("train.hyperparams", {"td3": {"batch_size": -1}}, r"train \(noadv, seed 0\): .*batch_size"),
    ("train.total_timesteps", "lots", r"train \(noadv, seed 0\): .*total_timesteps"),
    ("report.videos", "many", r"report.videos must be int"),
    ("backend.name", "slurm", r"backend.name must be local or ray"),
    ("backend.fit_workers", 0, r"backend.fit_workers must be at least 1"),
    ("backend.fit_workers", "two", r"backend.fit_workers must be int"),
])
def test_a_bad_value_anywhere_fails_before_anything_is_written(
    tmp_path: Path, key: str, value: object, message: str,
) -> None:
    preset = tmp_path / "preset.yaml"
    preset.write_text(yaml.safe_dump(_nested(GOOD, key, value), sort_keys=False))
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=message):
        run_pipeline(preset, out, progress=False)
    assert not out.exists()


def test_the_shipped_presets_pass_the_check(tmp_path: Path) -> None:
    from seal.experiments.pipeline.plan import check_plan
    from seal.experiments.pipeline.run import FIT_OUTPUTS, load_run_config, train_config

    configs = Path(__file__).resolve().parents[2] / "experiments" / "configs"
    for name in ("quick", "standard", "paper"):
        path = configs / f"{name}.yaml"
        check_plan(load_run_config(path), path, tmp_path / name, train_config, FIT_OUTPUTS)
        assert not (tmp_path / name).exists()
