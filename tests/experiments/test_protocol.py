"""One evaluation protocol: ``seal eval generators``, ``seal eval runs`` and the report's videos play the same
episode for the same scenario, ego, generator and seed (`seal.experiments.evaluation.protocol`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from seal.adversaries.base import AdversaryGenerator, Generation, register
from seal.core.dataset import load_split
from seal.core.scenario import CURRENT_STEP, Scenario, X, Y
from seal.envs.behaviors import TrackingBehavior
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation import protocol
from seal.experiments.evaluation.evaluate import resolve_eval_config
from seal.experiments.evaluation.generators import evaluate_generators
from seal.experiments.evaluation.parallel import evaluate_runs
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.training.egos import HeuristicEgo

SEED, K = 7, 2


@register("test_jitter")
class JitterGenerator(AdversaryGenerator):
    """Test-only generator whose episode depends on its rng: the logged adversary path shifted by a random offset."""

    def _generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
        track = scenario.track(scenario.adv_id).astype(np.float64)
        offset = rng.normal(scale=1.5, size=2)
        return Generation(TrackingBehavior(track[:, [X, Y]] + offset, start_step=0))



def test_episode_seed_and_generator_stream() -> None:
    assert protocol.episode_seed_of(0, 3) == 3000 and protocol.episode_seed_of(2, 1) == 2 * 1_000_003 + 1000
    assert protocol.generator_stream("cat") == protocol.generator_stream("cat") != protocol.generator_stream("rule")


@pytest.mark.parametrize("name", ["cat", "test_jitter"])
def test_generators_eval_and_runs_eval_play_the_same_episodes(name: str, dataset: Path, tmp_path: Path) -> None:
    """Same scenario, ego, generator and seed: the scored pass of ``seal eval generators`` (with another generator
    evaluated before it) is the row ``seal eval runs`` stores and the roll-out the report's videos replay."""
    store_path = tmp_path / "r.sqlite"
    evaluate_runs(["heuristic"], name, store_path, dataset=dataset, replay_ego=False,
                  config=resolve_eval_config(candidates="lanes", k=K, seed=SEED), progress=False)
    with ResultsStore(store_path) as store:
        rows = {r["scenario_id"]: r for r in store.episodes(setting=name)}
    scenarios = load_split(dataset, "eval")
    shared = {"candidates": "lanes"}
    # another generator evaluated first: a generator's rng stream does not depend on its neighbours
    generators = {g: protocol.build_generator(g, {}, shared) for g in ("rule", name)}
    _, records = evaluate_generators(scenarios, generators, "heuristic", k=K, seed=SEED, progress=False)
    by_id = {r.scenario_id: r for r in records if r.generator == name}
    assert set(by_id) == set(rows) == {s.scenario_id for s in scenarios}
    env, ego = ScenarioEnv(scenarios), HeuristicEgo()
    video_generator = protocol.build_generator(name, {}, shared)
    for i, sc in enumerate(scenarios):
        record, row = by_id[sc.scenario_id], rows[sc.scenario_id]
        assert (record.outcome, record.adv_collision) == (row["outcome"], bool(row["adv_collision"]))
        assert record.route_completion == pytest.approx(row["route_completion"], abs=1e-12)
        assert len(record.generation_times_s) == row["generations"] == K
        # the report's videos: the same calls, the same executed tracks
        normal = protocol.normal_episode(env, sc, i, ego, SEED)
        rollout, _ = protocol.scored_pass(env, sc, i, ego, video_generator, K, SEED, normal)
        replayed = rollout.ego_track[CURRENT_STEP:rollout.last_step + 1].astype(np.float64)
        np.testing.assert_array_equal(replayed, record.ego_track)
        if name == "test_jitter":  # the check has teeth: another rng stream plays another episode
            video_generator.name = "another"
            other, _ = protocol.scored_pass(env, sc, i, ego, video_generator, K, SEED, normal)
            video_generator.name = name
            assert not np.array_equal(other.adv_track, rollout.adv_track)
    env.close()


def test_generator_paths_starting_with_tilde_are_expanded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A model path written ``~/...`` in a YAML config reaches the generator as the home folder's path (the rcg
    generator checks that its behaviour file exists, so an unexpanded path would be an error)."""
    monkeypatch.setenv("HOME", str(tmp_path))
    got: dict[str, object] = {}

    @register("tilde_probe")
    class _Probe(AdversaryGenerator):
        def __init__(self, model: str = "", prior: str | None = None, count: int = 0) -> None:
            got.update(model=model, prior=prior, count=count)

        def _generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
            raise NotImplementedError

    protocol.build_generator("probe", {"generator": "tilde_probe", "model": "~/m.zip", "count": 3},
                             {"prior": "~/p.pt", "unused": "~/x"})
    assert got == {"model": str(tmp_path / "m.zip"), "prior": str(tmp_path / "p.pt"), "count": 3}
    from seal.adversaries.base import make_generator

    make_generator("tilde_probe", model="~user_is_not_home", prior="a/~b")
    assert got["prior"] == "a/~b"  # only a leading ~ is a home folder
