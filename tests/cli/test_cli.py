"""The command line: --help everywhere, clear errors for bad options and bad datasets."""

from __future__ import annotations

from pathlib import Path

import pytest

from seal.cli import build_parser, main


def _all_commands() -> list[list[str]]:
    """Every command path in the parser, found by walking its subparsers (so new commands are covered)."""
    seen: list[list[str]] = []

    def walk(p, prefix: list[str]) -> None:
        seen.append(prefix)
        for action in p._actions:
            if action.__class__.__name__ == "_SubParsersAction":
                for name, child in action.choices.items():
                    walk(child, [*prefix, name])

    walk(build_parser(), [])
    return seen


COMMANDS = _all_commands()


@pytest.mark.parametrize("words", COMMANDS, ids=lambda w: " ".join(w) or "seal")
def test_help_on_every_command(words: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*words, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "usage: seal" in out
    assert len(out.splitlines()) >= 4, f"`seal {' '.join(words)} --help` says almost nothing"


def test_the_documented_commands_exist() -> None:
    names = {" ".join(words) for words in COMMANDS}
    for expected in (
        "demo",
        "render",
        "data generate",
        "data info",
        "data score",
        "data split",
        "data report",
        "bench env",
        "bench data",
        "bench scoring",
    ):
        assert expected in names


def test_bad_options_name_the_option(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["data", "generate", "--out", "x", "--n", "3", "--layouts", "moon"])
    assert "--layouts" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["data", "generate", "--out", "x", "--n", "-3"])
    assert "--n must be positive" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["data", "generate", "--out", "x", "--n", "3", "--aggressive-share", "1.5"])
    assert "--aggressive-share must be in [0, 1]" in capsys.readouterr().err


def test_info_on_a_missing_dataset_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["data", "info", str(tmp_path / "nope")]) == 2
    assert "not a seal dataset" in capsys.readouterr().err


@pytest.mark.parametrize(
    "command", [["train", "--out", "{out}", "--config", "{bad}"], ["run", "{bad}", "--out", "{out}"]]
)
def test_invalid_yaml_is_one_line_naming_the_file(tmp_path, capsys, command) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("pipelines: [noadv\n")
    argv = [a.format(out=tmp_path / "out", bad=bad) for a in command]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{bad}, line 2, column 1: not valid YAML" in err[0]
    assert not (tmp_path / "out").exists()  # refused before anything was written


@pytest.mark.parametrize(("setting", "message"), [
    ("hyperparams.td3.batch_size=-1", "TD3Hyperparams.batch_size must be >= 1, got -1"),
    ("hyperparams.td3.learning_rate=-1", "TD3Hyperparams.learning_rate must be > 0, or an rl-zoo schedule "
     "lin_<start> with start > 0, got -1.0"),
    ("hyperparams.td3.learning_rate=fast", "learning_rate must be > 0, or an rl-zoo schedule lin_<start> with "
     "start > 0, got 'fast'"),
    ("total_timesteps=0", "EgoTrainConfig.total_timesteps must be >= 1, got 0"),
])
def test_train_refuses_bad_values_before_writing(tmp_path, capsys, setting: str, message: str) -> None:
    preset = Path(__file__).resolve().parents[2] / "experiments" / "configs" / "quick.yaml"
    out = tmp_path / "run"
    assert main(["train", "--config", str(preset), "--pipeline", "noadv", "--set", setting, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not out.exists()


def test_a_closed_stdout_is_no_traceback(tmp_path: Path) -> None:
    """`seal data info DIR | head -0`: the reader is gone before seal writes; seal stops quietly with the status
    `ls` or `git log` have there (141, killed by SIGPIPE as the shell reports it)."""
    import subprocess
    import sys

    import scenario_factory as sf

    from seal.core.dataset import write_dataset

    write_dataset(tmp_path / "ds", [sf.highway_scenario(i) for i in range(3)])
    proc = subprocess.Popen([sys.executable, "-m", "seal", "data", "info", str(tmp_path / "ds")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # as `head` does once it has what it wants
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141
    assert "Traceback" not in err and "BrokenPipe" not in err and "Exception ignored" not in err, err


def test_fewer_eval_scenarios_than_eval_episodes_is_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture,
) -> None:
    from train_fixtures import tiny_dataset, tiny_train_config

    from seal.experiments.training.train import train_run

    config = tiny_train_config(tiny_dataset(tmp_path))  # 2 eval scenarios
    config.update(n_envs=1, total_timesteps=40, checkpoint_every=0, eval_every=40, eval_episodes=20)
    with caplog.at_level("WARNING", logger="seal.experiments.training.train"):
        train_run(config, tmp_path / "run", progress=False)
    assert "eval_episodes is 20 but the 'eval' split" in caplog.text and "has 2 scenarios" in caplog.text
    evaluated = (tmp_path / "run" / "eval" / "evaluations.csv").read_text().splitlines()
    assert len(evaluated) == 2  # header + the evaluation at step 40
