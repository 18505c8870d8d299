"""Third-party generators (issue 25): the README's `--plugin` generator and one from a tiny installed package
(entry point) appear in `seal eval generators` and train through `seal train --pipeline`; consistent training
logs."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import yaml
from readme_blocks import block
from train_fixtures import tiny_dataset

from seal.adversaries.base import available_generators, generator_class
from seal.cli import main

PACKAGE = '''
import os
from seal.adversaries.base import AdversaryGenerator, Generation
from seal.envs.behaviors import ReplayBehavior


def make_policy():
    """An ego policy from the package: full brake."""
    return lambda obs: [0.0, -1.0]


class HardBrake(AdversaryGenerator):
    """Replays the logged adversary and notes each call in $SEAL_TEST_PLUGIN_LOG."""

    def _generate(self, scenario, history, rng):
        with open(os.environ["SEAL_TEST_PLUGIN_LOG"], "a") as f:
            f.write(scenario.scenario_id + "\\n")
        return Generation(behavior=ReplayBehavior())
'''


def install_package(site: Path) -> None:
    """A tiny installed distribution: the package and its dist-info with a ``seal.generators`` entry point."""
    (site / "seal_test_plugin").mkdir(parents=True)
    (site / "seal_test_plugin" / "__init__.py").write_text(PACKAGE)
    info = site / "seal_test_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: seal-test-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[seal.generators]\nhardbrake = seal_test_plugin:HardBrake\n\n"
                                           "[seal.egos]\nbrake-ego = seal_test_plugin:make_policy\n")


def train_yaml(tmp_path: Path, data: Path, eval_every: int = 0, n_envs: int = 1) -> Path:
    path = tmp_path / "train.yaml"
    path.write_text(f"""
train:
  dataset: {data}
  total_timesteps: 240
  n_envs: {n_envs}
  eval_every: {eval_every}
  eval_episodes: 5
  checkpoint_every: 0
  curriculum: {{slope: 100.0, cap: 1.0}}
  hyperparams: {{td3: {{learning_starts: 40, batch_size: 16, net_arch: [16, 16], buffer_size: 400}}}}
  pipelines: {{brake: {{name: brake, kwargs: {{decel_mps2: 8.0}}}}}}
""")
    return path


def _csv(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open()))


@pytest.fixture(autouse=True)
def isolated_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    """Generators registered by a test's plugins, the plugins loaded and SEAL_PLUGINS are undone after it, so no
    other test sees a 'brake' generator."""
    from seal.adversaries import base
    from seal.core import plugins

    monkeypatch.setattr(base, "_REGISTRY", dict(base._REGISTRY))
    monkeypatch.setattr(plugins, "_LOADED", dict(plugins._LOADED))
    monkeypatch.setenv(plugins.PLUGIN_ENV, "")


def test_readme_plugin_generator_evaluates_and_trains(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    from multiprocessing import forkserver

    # SB3 env workers fork from a forkserver; one started before --plugin (as in any long-lived process) never
    # sees SEAL_PLUGINS: the plugin must reach the workers with their env functions
    forkserver.ensure_running()
    monkeypatch.chdir(tmp_path)
    data = tiny_dataset(tmp_path)
    (tmp_path / "my_brake.py").write_text(block("Use your own policy / generator", "# my_brake.py"))
    code = main(["eval", "generators", str(data), "--plugin", "my_brake.py", "--generators", "replay,brake",
                 "--ego", "heuristic", "--out", "gen-brake", "--no-progress"])
    assert code == 0, capsys.readouterr().err
    assert "brake" in available_generators()
    rows = {r["generator"]: r for r in _csv(tmp_path / "gen-brake" / "generators.csv")}
    assert set(rows) == {"replay", "brake"}
    # the brake generator changed the adversary's accelerations (replay's distance to the log is ~0)
    assert float(rows["brake"]["acc_wd"]) > 1.0 > 0.01 > float(rows["replay"]["acc_wd"])

    # two env worker processes: the plugin reaches them through SEAL_PLUGINS
    config = train_yaml(tmp_path, data, eval_every=240, n_envs=2)
    code = main(["train", "--config", str(config), "--plugin", "my_brake.py", "--pipeline", "brake", "--out",
                 "runs/brake-s0", "--no-progress", "--json"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "eval_episodes is 5 but the 'eval' split" in err and "has 2 scenarios" in err  # said, not silent
    run = tmp_path / "runs" / "brake-s0"
    done = json.loads((run / "done.json").read_text())
    assert done["steps"] == 240 and done["session_totals"]["perturbed"] > 0
    with open(run / "eval" / "evaluations.csv") as f:
        assert [int(r["episodes"]) for r in csv.DictReader(f)] == [2]
    # the README's third line: the run evaluates against its own generator (its config records the pipeline)
    code = main(["eval", "runs", "runs/brake-s0", "--plugin", "my_brake.py", "--settings", "normal,brake", "--store",
                 "results.sqlite", "--workers", "1", "--k", "1", "--no-progress"])
    assert yaml.safe_load((run / "config.yaml").read_text())["plugins"] == [str(tmp_path / "my_brake.py")]
    assert code == 0, capsys.readouterr().err
    from seal.experiments.evaluation.results_store import ResultsStore

    with ResultsStore(tmp_path / "results.sqlite") as store:
        assert {(r["pipeline"], r["setting"]) for r in store.episodes()} >= {("brake", "brake"), ("brake", "normal")}
        assert {s["setting"]: s["kwargs"] for s in store.settings()}["brake"] == {"decel_mps2": 8.0}
    # evaluation chunk jobs name the plugin, for workers that do not inherit SEAL_PLUGINS (Ray)
    from seal.experiments.evaluation.evaluate import parse_settings, read_run, resolve_eval_config
    from seal.experiments.evaluation.parallel import chunk_jobs

    jobs = chunk_jobs(str(tmp_path / "fresh.sqlite"), [read_run(run)], parse_settings("brake", data),
                      resolve_eval_config(run_configs=[read_run(run).config]))
    assert jobs and all(job["plugins"] == [str(tmp_path / "my_brake.py")] for job in jobs)
    progress = _csv(run / "progress.csv")
    assert any(r.get("curriculum/p") for r in progress)  # a perturbing pipeline logs p
    last = [r["episode/crash_rate"] for r in progress if r.get("episode/crash_rate")][-1]
    assert done["final_rates"]["crash_rate"] == pytest.approx(float(last))  # done.json agrees with the log
    totals = done["session_totals"]
    assert totals["crashed"] >= totals["crash"] and totals["episodes"] == sum(
        totals[o] for o in ("success", "crash", "out_of_road", "timeout"))


def test_installed_entry_point_generator(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    install_package(tmp_path / "site")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path / "site"))  # spawned env workers see the package too
    log = tmp_path / "calls.txt"
    monkeypatch.setenv("SEAL_TEST_PLUGIN_LOG", str(log))
    data = tiny_dataset(tmp_path)
    assert "hardbrake" in available_generators()
    assert generator_class("hardbrake").__name__ == "HardBrake"
    code = main(["eval", "generators", str(data), "--generators", "replay,hardbrake", "--ego", "heuristic",
                 "--k", "2", "--out", str(tmp_path / "gen"), "--no-progress"])
    assert code == 0, capsys.readouterr().err
    assert len(log.read_text().split()) == 2 * 2  # 2 eval scenarios x K = 2 passes
    log.unlink()
    config = train_yaml(tmp_path, data)
    code = main(["train", "--config", str(config), "--pipeline", "hardbrake", "--out", str(tmp_path / "run"),
                 "--no-progress"])
    assert code == 0, capsys.readouterr().err
    assert log.is_file() and log.read_text().split()  # the training workers called it
    recorded = (tmp_path / "run" / "config.yaml").read_text()
    assert "name: hardbrake" in recorded
    # the package's ego evaluates by name, and plays as the policy it returns (never moving: timeouts)
    store = tmp_path / "r.sqlite"
    code = main(["eval", "runs", "--ego", "brake-ego", "--dataset", str(data), "--settings", "normal,hardbrake",
                 "--store", str(store), "--no-replay-ego", "--workers", "1", "--k", "1", "--no-progress"])
    assert code == 0, capsys.readouterr().err
    from seal.experiments.evaluation.results_store import ResultsStore

    with ResultsStore(store) as s:
        rows = s.episodes(run="brake-ego")
    assert {(r["setting"], r["outcome"]) for r in rows} == {("normal", "timeout"), ("hardbrake", "timeout")}
    # an unknown pipeline is refused with the names it could be
    code = main(["train", "--config", str(config), "--pipeline", "nosuch", "--out", str(tmp_path / "x")])
    assert code == 2 and "nosuch" in capsys.readouterr().err


def test_noadv_does_not_log_curriculum_p() -> None:
    from seal.experiments.training.curriculum import CurriculumCallback

    class Logger:
        def __init__(self) -> None:
            self.keys: list[str] = []

        def record(self, key: str, value: float) -> None:
            self.keys.append(key)

    class Env:
        def env_method(self, *args: object) -> None:
            pass

    class Model:
        def __init__(self) -> None:
            self.logger = Logger()

        def get_env(self) -> Env:
            return Env()

    for log, expected in ((True, ["curriculum/p"]), (False, [])):
        cb = CurriculumCallback(100, log=log)
        cb.model, cb.num_timesteps = Model(), 50  # what SB3's init_callback / on_step set
        cb._on_step()
        assert cb.model.logger.keys == expected and cb.p == pytest.approx(0.9)
