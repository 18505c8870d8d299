"""The roll-out queues across processes: two spawned SubprocVecEnv workers, scenarios partitioned between them.
Every roll-out a worker produces must be the newest entry of the queue its generator reads the next time that
scenario is perturbed, and the queues fetched back from the workers must match the episodes seen here."""

from __future__ import annotations

import numpy as np
import scenario_factory as sf
from stable_baselines3.common.vec_env import SubprocVecEnv

from seal.adversaries.closed_loop import closed_loop_env_fns
from seal.adversaries.history import RolloutHistory, rollout_digest
from seal.envs.heuristic import HeuristicDriver

K = 3


def test_rollouts_reach_the_queue_of_the_next_perturbation_across_processes() -> None:
    scenarios = [sf.highway_scenario(i) for i in range(4)]
    ids = [s.scenario_id for s in scenarios]
    fns = closed_loop_env_fns(scenarios, n_workers=2, generator="rule", k=K, env_config={"horizon_steps": 30})
    venv = SubprocVecEnv(fns, start_method="spawn")
    try:
        venv.seed(7)
        # Each scenario lives in exactly one worker.
        parts = venv.get_attr("scenario_ids")
        assert sorted(sum(parts, [])) == sorted(ids) and not set(parts[0]) & set(parts[1])
        worker_of = {sid: w for w, part in enumerate(parts) for sid in part}
        obs = venv.reset()
        # What this process expects each queue to hold: K logged copies, then every finished roll-out.
        logged = RolloutHistory(K)
        expected = {s.scenario_id: logged.digests(s) for s in scenarios}
        current = [dict(info) for info in venv.reset_infos]
        driver = HeuristicDriver()
        checked = dict.fromkeys(ids, 0)
        for _ in range(400):
            obs, _, dones, infos = venv.step(driver.predict(obs)[0])
            for w in np.flatnonzero(dones):
                info = infos[w]
                sid = info["scenario_id"]
                assert worker_of[sid] == w
                # The generator of that episode read the queue as this process predicted it.
                assert current[w]["adversary"]["history"] == expected[sid]
                checked[sid] += 1
                # The roll-out as it arrived here, hashed here.
                assert info["rollout_digest"] == rollout_digest(info["rollout"])
                expected[sid] = expected[sid][1:] + [rollout_digest(info["rollout"])]
                current[w] = dict(venv.reset_infos[w])
            if min(checked.values()) >= 2:
                break
        assert min(checked.values()) >= 2, checked  # every scenario was perturbed again after a roll-out
        # The queues inside the workers are the ones this process reconstructed.
        for w, history in enumerate(venv.get_attr("history")):
            for sid in parts[w]:
                scenario = next(s for s in scenarios if s.scenario_id == sid)
                assert history.digests(scenario) == expected[sid]
    finally:
        venv.close()
