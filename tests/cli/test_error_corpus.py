"""A corpus of malformed inputs: every `seal` command answers each with exit code 2 and one line on stderr that
names the culprit (file, field or option), never a traceback, and writes nothing."""

from __future__ import annotations

import json
import pickle
from collections.abc import Callable
from pathlib import Path

import pytest
import scenario_factory as sf

from seal.cli import main
from seal.core.dataset import Dataset, write_dataset


def _dataset(root: Path) -> Path:
    write_dataset(root, [sf.highway_scenario(i) for i in range(3)])
    return root


def _edit_manifest(root: Path, edit: Callable[[dict], object]) -> Path:
    """Apply ``edit`` to the manifest in place (``edit`` mutates it, or returns a whole replacement dict / value
    wrapped in a 1-tuple)."""
    path = root / "manifest.json"
    manifest = json.loads(path.read_text())
    result = edit(manifest)
    path.write_text(json.dumps(result[0] if isinstance(result, tuple) else manifest))
    return root


class _Hostile:
    """Unpickling this would run a shell command: the restricted loader must refuse it."""

    def __reduce__(self):  # noqa: ANN204
        import os

        return (os.system, ("touch /tmp/seal-hostile-pickle-ran",))


def _case_manifest_is_a_number(tmp: Path) -> tuple[list[str], str]:
    root = _edit_manifest(_dataset(tmp / "ds"), lambda m: (42,))
    return ["data", "info", str(root)], "manifest.json"


def _case_shard_without_sha256(tmp: Path) -> tuple[list[str], str]:
    root = _edit_manifest(_dataset(tmp / "ds"), lambda m: m["shards"][0].pop("sha256") and None)
    return ["data", "info", str(root)], "sha256"


def _case_no_shards(tmp: Path) -> tuple[list[str], str]:
    root = _edit_manifest(_dataset(tmp / "ds"), lambda m: m.update(shards=[]))
    return ["data", "info", str(root)], "manifest.json"


def _case_a_shard_entry_removed(tmp: Path) -> tuple[list[str], str]:
    write_dataset(tmp / "ds", [sf.highway_scenario(i) for i in range(6)], shard_size=2)
    root = _edit_manifest(tmp / "ds", lambda m: m["shards"].pop() and None)
    return ["data", "info", str(root)], "counts.scenarios"


def _case_truncated_shard(tmp: Path) -> tuple[list[str], str]:
    root = _dataset(tmp / "ds")
    shard = next((root / "shards").glob("*.npz"))
    shard.write_bytes(shard.read_bytes()[:100])
    return ["data", "info", str(root)], shard.name


def _case_compare_on_a_text_file(tmp: Path) -> tuple[list[str], str]:
    store = tmp / "notes.sqlite"
    store.write_text("not a database")
    return ["compare", "--store", str(store), "--out", str(tmp / "out")], "notes.sqlite"


def _case_split_before_scoring(tmp: Path) -> tuple[list[str], str]:
    return ["data", "split", str(_dataset(tmp / "ds"))], "seal data score"


def _case_run_eval_is_a_number(tmp: Path) -> tuple[list[str], str]:
    preset = tmp / "p.yaml"
    preset.write_text("pipelines: [noadv]\nseeds: [0]\ndata: {generate: {n: 3}}\neval: 5\ntrain: {algo: td3}\n")
    return ["run", str(preset), "--out", str(tmp / "out")], "eval"


def _case_run_curriculum_is_a_number(tmp: Path) -> tuple[list[str], str]:
    preset = tmp / "p.yaml"
    preset.write_text("pipelines: [noadv]\nseeds: [0]\ndata: {generate: {n: 3}}\ntrain: {algo: td3, curriculum: 5}\n")
    return ["run", str(preset), "--out", str(tmp / "out")], "curriculum"


def _train(tmp: Path, setting: str) -> list[str]:
    preset = Path(__file__).resolve().parents[2] / "experiments" / "configs" / "quick.yaml"
    dataset = _dataset(tmp / "ds")
    Dataset.open(dataset).update_manifest(splits={"train": ["highway-0", "highway-1"], "eval": ["highway-2"]})
    return ["train", "--config", str(preset), "--pipeline", "noadv", "--set", f"dataset={dataset}", "--set", setting,
            "--out", str(tmp / "out")]


def _case_train_unknown_env_key(tmp: Path) -> tuple[list[str], str]:
    return _train(tmp, "env.warp_speed=9"), "warp_speed"


def _case_train_steps_in_words(tmp: Path) -> tuple[list[str], str]:
    return _train(tmp, "total_timesteps=lots"), "total_timesteps"


def _case_train_curriculum_is_a_number(tmp: Path) -> tuple[list[str], str]:
    return _train(tmp, "curriculum=5"), "curriculum"


def _case_malformed_commonroad_xml(tmp: Path) -> tuple[list[str], str]:
    src = tmp / "src"
    src.mkdir()
    (src / "broken.xml").write_text("<commonRoad><lanelet id='1'>")
    return ["data", "import", "commonroad", str(src), "--out", str(tmp / "out"), "--no-progress"], "broken.xml"


def _case_hostile_scenarionet_pickle(tmp: Path) -> tuple[list[str], str]:
    src = tmp / "src"
    src.mkdir()
    (src / "evil.pkl").write_bytes(pickle.dumps({"tracks": _Hostile()}))
    return ["data", "import", "scenarionet", str(src), "--out", str(tmp / "out"), "--no-progress"], "evil.pkl"


def _case_eval_of_a_folder_without_a_run(tmp: Path) -> tuple[list[str], str]:
    (tmp / "empty").mkdir()
    return ["eval", "runs", str(tmp / "empty"), "--dataset", str(_dataset(tmp / "ds"))], "empty"


def _case_objective_retest_of_deterministic_labels(tmp: Path) -> tuple[list[str], str]:
    # Replayed candidates against the heuristic ego: every seed gives the same labels, so a retest is refused.
    return ["eval", "objective", str(tmp / "objective.pt"), str(_dataset(tmp / "ds")), "--candidates", "lanes",
            "--retest-seed", "1", "--out", str(tmp / "out")], "--retest-seed"


def _case_objective_retest_labels_without_a_seed(tmp: Path) -> tuple[list[str], str]:
    return ["eval", "objective", str(tmp / "objective.pt"), str(_dataset(tmp / "ds")), "--candidates", "lanes",
            "--retest-labels", str(tmp / "out" / "second"), "--out", str(tmp / "out")], "--retest-labels"


CASES = {name[len("_case_"):]: fn for name, fn in list(globals().items()) if name.startswith("_case_")}


@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_input_is_one_line_and_exit_2(case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv, culprit = CASES[case](tmp_path)
    capsys.readouterr()
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("seal: error: ") and culprit in lines[0]
    assert "Traceback" not in captured.err + captured.out
    assert not (tmp_path / "out").exists()
    assert not Path("/tmp/seal-hostile-pickle-ran").exists()
