"""Simulated labels for pi_score (thesis 6.3.1): every candidate adversary future rolled out against an ego.

Two label behaviours (`LabelBehavior`, issue 16): ``replay`` (below: the adversary replays the candidate, as CAT
does) and ``seal``: the adversary does what SEAL does with a chosen candidate (`seal.adversaries.seal.generator`):
it follows the candidate and, ``switch_offset_steps`` before the contact predicted against the previous roll-out
(the logged-adversary episode, `seal.adversaries.seal.contact.predict_contact`), hands over to the adversarial skill
policy (`SkillSwitchBehavior`, noise seeded per scenario, ego and candidate) and ``adversarial_steps`` later to the
benign prior's skills, as the generator does. So the learned objective predicts the
outcome of the behaviour it selects. Every ego in ``egos`` (the heuristic driver and `seal train` checkpoints) gives
its own row of the `LabelSet` (the scenario id repeated), so the labels cover egos that brake, stop or weave.

Per scenario: the candidate source (the trajectory prior pi_gen) gives N = 32 candidates for the adversary. The
heuristic ego (`seal.experiments.training.egos.HeuristicEgo`) plays one episode against the logged adversary and one
against
each candidate, which the adversary replays kinematically (`ReplayBehavior(candidate_track(...))`, as CAT does).
The heuristic ego is deterministic given the adversary, so each of these M = N + 1 ego roll-outs is a valid
"previous roll-out" for every candidate j: the scenario yields M x N pairs (see `seal.models.objective.labels`).

Labels (`seal.scoring.criticality`, b = 8 m), over the candidates' steps ``CURRENT_STEP + 1 .. CURRENT_STEP + 80``:

* ``f_coll[j]``: ego vs adversary positions of episode j over the steps where both exist; 1 when the ego hit
  the adversary (a crash with a third vehicle does not count: f_coll measures ego-adversary closeness).
* ``f_diff[i, j]``: ego of episode j vs ego of episode i. An episode that ended early (crash, leaving the road,
  arrival) keeps the ego at its last position for the rest of the horizon: a crash at step 30 is a large change
  of behaviour from an episode that drove on, not a shorter comparison.

Also stored: CAT's heuristic score of each candidate against the logged-adversary roll-out (`cat_select`, the
report's baseline) and the prior's probabilities.

Building is resumable and parallel: scenarios are cut into chunks of ``chunk_size``; each finished chunk is an
``.npz`` (atomic write) in the output folder and is skipped by a re-run with the same settings (a
``state.json`` fingerprint of scenarios and settings guards against mixing runs).
"""

from __future__ import annotations

import hashlib
import logging
import zlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.chunked import fingerprint, run_chunked
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, N_FUTURE, VALID, WIDTH, Scenario, X, Y
from seal.envs.skill_behavior import ADVERSARIAL_STEPS, SKILL_NOISE_SCALE
from seal.models.objective.labels import LabelSet

logger = logging.getLogger(__name__)

N_CANDIDATES = 32
"""Candidates per scenario (pi_gen's mode count)."""
LABEL_FORMAT = 4
"""Bumped when the label definition changes (invalidates finished chunks)."""

_SOURCE_CACHE: dict[str, Any] = {}


def _candidate_source(spec: str) -> Any:
    """The candidate source for ``spec`` ("prior:<path>" or a built-in name), built once per process."""
    if spec not in _SOURCE_CACHE:
        from seal.adversaries.candidate_sources import named_source, prior_source

        _SOURCE_CACHE[spec] = prior_source(spec[len("prior:"):]) if spec.startswith("prior:") else named_source(spec)
    return _SOURCE_CACHE[spec]


def source_spec(prior: str | Path | None = None, candidates: str | None = None) -> str:
    """The candidate source as a string that worker processes can rebuild: exactly one of a prior file or a
    built-in name (`seal.adversaries.candidate_sources.NAMED_SOURCES`)."""
    from seal.adversaries.candidate_sources import NAMED_SOURCES

    if (prior is None) == (candidates is None):
        raise ValueError("objective labels need exactly one candidate source: a trajectory prior file (--prior FILE, "
                         f"'prior:' in configs) or a built-in source ({', '.join(NAMED_SOURCES)}: --candidates NAME)")
    if prior is not None:
        path = Path(prior)
        if not path.is_file():
            raise FileNotFoundError(f"trajectory prior file {path} does not exist (fit one with `seal fit prior`)")
        return f"prior:{path.resolve()}"
    if candidates not in NAMED_SOURCES:
        raise ValueError(f"unknown candidate source {candidates!r}; choose from {', '.join(NAMED_SOURCES)}")
    return str(candidates)


def _future(track: np.ndarray, n_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xy ``[n, 2]``, heading ``[n]``, valid ``[n]`` of a ``[T, 8]`` track at steps CURRENT_STEP + 1 .. + n."""
    out = np.zeros((n_steps, 8))
    part = track[CURRENT_STEP + 1 : CURRENT_STEP + 1 + n_steps]
    out[: len(part)] = part
    return out[:, [X, Y]], out[:, HEADING], out[:, VALID] > 0.5


def hold_last(xy: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``[..., T, 2]`` positions with every step after the last valid one (and any gap) held at the last valid
    position; steps before the first valid one take the first valid position."""
    n = valid.shape[-1]
    idx = np.broadcast_to(np.arange(n), valid.shape)
    last = np.maximum.accumulate(np.where(valid, idx, -1), axis=-1)
    first = np.argmax(valid, axis=-1)[..., None]
    src = np.where(last < 0, first, last)
    return np.take_along_axis(xy, src[..., None].repeat(2, axis=-1), axis=-2)


LABEL_BEHAVIORS = ("replay", "seal")
"""How the adversary drives each candidate in the label roll-outs (module docstring)."""


@dataclass(frozen=True)
class LabelBehavior:
    """The adversary behaviour and the ego of the label roll-outs.

    Attributes:
        kind: ``replay`` or ``seal`` (`LABEL_BEHAVIORS`).
        skills: skills folder of the ``seal`` behaviour (`seal fit skills`).
        switch_offset_steps: steps between the switch to the skill policy and the predicted contact.
        adversarial_steps: steps the adversarial skills drive after the switch before the benign prior's take over
            (None: to the end), as the generator (`seal.envs.skill_behavior.ADVERSARIAL_STEPS`).
        noise_scale: skill noise scale of the ``seal`` behaviour.
        seed: base seed of the skill noise.
    """

    kind: str = "replay"
    skills: str | None = None
    switch_offset_steps: int = 10
    noise_scale: float = SKILL_NOISE_SCALE
    seed: int = 0
    adversarial_steps: int | None = ADVERSARIAL_STEPS

    def __post_init__(self) -> None:
        if self.adversarial_steps is not None and int(self.adversarial_steps) < 0:
            raise ValueError(f"objective labels: adversarial_steps must be >= 0 or null, got {self.adversarial_steps}")
        if self.kind not in LABEL_BEHAVIORS:
            raise ValueError(f"objective labels: behavior must be one of {LABEL_BEHAVIORS}, got {self.kind!r}")
        if self.kind == "seal" and not self.skills:
            raise ValueError("objective labels: behavior 'seal' needs a skills folder (config key 'skills')")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


_POLICY_CACHE: dict[tuple[str, float, str], Any] = {}


def _skill_policy(behavior: LabelBehavior, prior: str = "adversarial") -> Any:
    key = (str(behavior.skills), behavior.noise_scale, prior)
    if key not in _POLICY_CACHE:
        from seal.adversaries.seal.generator import load_skill_policy

        _POLICY_CACHE[key] = load_skill_policy(behavior.skills, prior, behavior.noise_scale)
    return _POLICY_CACHE[key]


def _candidate_behaviors(scenario: Scenario, cands: Any, cand_xy: np.ndarray, logged: Any, behavior: LabelBehavior,
                         ego_index: int) -> list[Any]:
    """The adversary behaviour of every candidate: its replay, or SEAL's follow-then-switch (module docstring)."""
    from seal.adversaries.candidate_path import candidate_track
    from seal.adversaries.seal.contact import predict_contact
    from seal.envs.behaviors import ReplayBehavior
    from seal.envs.skill_behavior import SkillSwitchBehavior, switch_step_for

    adv = scenario.adv_index
    tracks = [candidate_track(scenario, adv, xy) for xy in cand_xy]
    if behavior.kind == "replay":
        return [ReplayBehavior(t) for t in tracks]
    policy = _skill_policy(behavior)
    benign = None if behavior.adversarial_steps is None else _skill_policy(behavior, "benign")
    ego = logged.ego_track.astype(np.float64)
    now = scenario.tracks[:, CURRENT_STEP]
    out = []
    for j, track in enumerate(tracks):
        contact = predict_contact(
            cand_xy[j], cands.heading[j, : cand_xy.shape[1]], (float(now[adv, LENGTH]), float(now[adv, WIDTH])),
            ego[None, :, [X, Y]], ego[None, :, HEADING], ego[None, :, VALID] > 0.5,
            (float(now[scenario.ego_index, LENGTH]), float(now[scenario.ego_index, WIDTH])))
        seed = zlib.crc32(f"{scenario.scenario_id}/{ego_index}/{j}/{behavior.seed}".encode())
        switch = switch_step_for(contact.step, behavior.switch_offset_steps)
        then = None if benign is None else benign.clone()
        then_step = None if then is None else switch + int(behavior.adversarial_steps or 0)
        out.append(SkillSwitchBehavior(policy.clone(), track=track, switch_step=switch, seed=seed, then=then,
                                       then_step=then_step))
    return out


def label_scenario(scenario: Scenario, source: Callable[[Scenario], Any], n_candidates: int = N_CANDIDATES,
                   n_steps: int = N_FUTURE, ego_spec: str = "heuristic", behavior: LabelBehavior | None = None,
                   ego_index: int = 0) -> LabelSet:
    """Roll out the logged adversary and every candidate (`LabelBehavior`) against the ego ``ego_spec``
    (``heuristic`` or a `seal train` run folder); a `LabelSet` of one row."""
    from seal.adversaries.cat.select import cat_select
    from seal.envs.behaviors import ReplayBehavior
    from seal.envs.scenario_env import ScenarioEnv
    from seal.experiments.evaluation.episodes import run_episode
    from seal.scoring.criticality import f_coll, f_diff

    behavior = behavior or LabelBehavior()

    adv = scenario.adv_index
    cands = source(scenario)
    if cands.agent_index != adv:
        raise ValueError(f"objective labels: candidates of scenario {scenario.scenario_id!r} are for agent index "
                         f"{cands.agent_index}, its adversary is index {adv}")
    if cands.n_candidates < n_candidates or cands.n_steps < n_steps:
        raise ValueError(f"objective labels: scenario {scenario.scenario_id!r} has {cands.n_candidates} candidates x "
                         f"{cands.n_steps} steps; need {n_candidates} x {n_steps} (set n_candidates lower)")
    cand_xy = cands.xy[:n_candidates, :n_steps]
    env = ScenarioEnv(scenario)
    ego = _ego(ego_spec)
    logged_rollout = run_episode(env, scenario, ego, ReplayBehavior())
    behaviors = _candidate_behaviors(scenario, cands, cand_xy, logged_rollout, behavior, ego_index)
    rollouts = [logged_rollout] + [run_episode(env, scenario, ego, b) for b in behaviors]
    env.close()

    m = n_candidates + 1
    ego_xy, ego_h, ego_v = np.zeros((m, n_steps, 2)), np.zeros((m, n_steps)), np.zeros((m, n_steps), dtype=bool)
    adv_xy, adv_v = np.zeros((m, n_steps, 2)), np.zeros((m, n_steps), dtype=bool)
    crashed = np.zeros(m, dtype=bool)
    for r, ro in enumerate(rollouts):
        ego_xy[r], ego_h[r], ego_v[r] = _future(ro.ego_track.astype(np.float64), n_steps)
        adv_xy[r], _, adv_v[r] = _future(ro.adv_track.astype(np.float64), n_steps)
        crashed[r] = any(other == ro.adv_id for _, other in ro.ego_crashes)
    coll = f_coll(ego_xy[1:], adv_xy[1:], crashed=crashed[1:], valid=ego_v[1:] & adv_v[1:])
    held = hold_last(ego_xy, ego_v)
    diff = f_diff(held[:, None], held[None, 1:])  # [M, N]: previous roll-out i, candidate j

    # CAT's score of each candidate against the logged-adversary roll-out (scenario-step indexed ego arrays).
    logged = rollouts[0].ego_track.astype(np.float64)
    now = scenario.tracks[:, CURRENT_STEP]
    sizes_m = now[[scenario.ego_index, adv]][:, [LENGTH, WIDTH]].astype(np.float64)  # rows: ego, adversary
    sel = cat_select(
        cand_xy, cands.heading[:n_candidates, :n_steps], cands.probs[:n_candidates],
        adv_size_m=(float(sizes_m[1, 0]), float(sizes_m[1, 1])),
        ego_xy=logged[None, :, [X, Y]], ego_heading=logged[None, :, HEADING], ego_valid=logged[None, :, VALID] > 0.5,
        ego_size_m=(float(sizes_m[0, 0]), float(sizes_m[0, 1])),
    )
    return LabelSet(
        scenario_ids=np.array([scenario.scenario_id]),
        cand_xy=cand_xy[None].astype(np.float32),
        cand_heading=cands.heading[None, :n_candidates, :n_steps].astype(np.float32),
        probs=cands.probs[None, :n_candidates].astype(np.float32),
        ego_xy=ego_xy[None].astype(np.float32), ego_heading=ego_h[None].astype(np.float32), ego_valid=ego_v[None],
        f_coll=coll[None].astype(np.float32), f_diff=diff[None].astype(np.float32), crashed=crashed[None, 1:],
        cat_score=np.asarray(sel.scores, dtype=np.float32)[None],
        adv_xy=adv_xy[None].astype(np.float32), adv_valid=adv_v[None],
        sizes_m=sizes_m[None].astype(np.float32),
    )


_EGO_CACHE: dict[str, Any] = {}


def _ego(spec: str) -> Any:
    """The ego of ``spec`` (`seal.experiments.training.egos.make_ego`), loaded once per process."""
    if spec not in _EGO_CACHE:
        from seal.experiments.training.egos import make_ego

        _EGO_CACHE[spec] = make_ego(spec)
    return _EGO_CACHE[spec]


def _run_chunk(args: tuple[int, list[Scenario], str, int, list[str], dict[str, Any]]) -> tuple[int, LabelSet]:
    index, scenarios, spec, n_candidates, egos, behavior = args
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one thread per chunk worker; restored for a chunk run in the calling process
    try:
        source = _candidate_source(spec)
        b = LabelBehavior(**behavior)
        return index, LabelSet.concat([label_scenario(s, source, n_candidates, ego_spec=e, behavior=b, ego_index=k)
                                       for s in scenarios for k, e in enumerate(egos)])
    finally:
        torch.set_num_threads(threads)


def _content(path: str) -> str:
    """sha256 of a file, or of every file of a folder (sorted by name), so a retrained model invalidates labels."""
    p = Path(path)
    h = hashlib.sha256()
    for f in sorted(p.rglob("*.pt")) if p.is_dir() else [p]:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def _fingerprint(spec: str, ids: Sequence[str], chunk_size: int, n_candidates: int, egos: Sequence[str],
                 behavior: LabelBehavior) -> str:
    source = spec
    if spec.startswith("prior:"):  # the prior's content, not just its path
        source = _content(spec[len("prior:"):])
    b = behavior.to_dict()
    if behavior.skills:
        b["skills"] = _content(behavior.skills)
    return fingerprint({"source": source, "ids": list(ids), "chunk": chunk_size, "n": n_candidates,
                        "format": LABEL_FORMAT, "egos": list(egos), "behavior": b})


def build_labels(
    scenarios: Sequence[Scenario],
    out: str | Path,
    spec: str,
    n_candidates: int = N_CANDIDATES,
    workers: int = 2,
    chunk_size: int = 10,
    progress: bool = True,
    desc: str = "objective labels",
    egos: Sequence[str] = ("heuristic",),
    behavior: LabelBehavior | None = None,
    start_over: bool = True,
) -> LabelSet:
    """Label ``scenarios`` in ``workers`` processes into chunk files ``out/part_NNNNN.npz`` (resumable, see the
    module docstring) and return all of them as one `LabelSet`, in scenario order.

    Args:
        scenarios: the scenarios to label.
        out: folder of the chunk files (created).
        spec: candidate source, from `source_spec`.
        n_candidates: candidates kept per scenario (the first, most probable).
        workers: processes (spawned; each uses one torch thread).
        chunk_size: scenarios per chunk file.
        progress: show a tqdm bar.
        desc: the bar's label.
        egos: ego specs; each scenario gives one row per ego (in this order).
        behavior: the adversary behaviour of the candidates (default: replay).
        start_over: ``out`` holding labels of other settings is emptied; False raises ValueError instead
            (`seal.core.chunked.run_chunked`).

    Resuming / restarting is reported through this module's logger.
    """
    if not scenarios:
        raise ValueError("build_labels: no scenarios")
    out = Path(out)
    behavior = behavior or LabelBehavior()
    egos = [str(e) for e in egos]
    if not egos:
        raise ValueError("objective labels: no egos (config key 'egos')")
    ids = [s.scenario_id for s in scenarios]
    path = run_chunked(
        scenarios, out, _fingerprint(spec, ids, chunk_size, n_candidates, egos, behavior),
        {"n_candidates": n_candidates, "source": spec, "egos": egos, "behavior": behavior.to_dict()}, _run_chunk,
        (spec, n_candidates, egos, behavior.to_dict()),
        lambda labels, file: labels.save(file), workers, chunk_size, progress, desc, start_over,
    )
    merged = LabelSet.concat([LabelSet.load(p) for p in path])
    if list(merged.scenario_ids) != [i for i in ids for _ in egos]:
        raise ValueError(f"{desc}: chunk files in {out} do not match the scenarios; delete the folder and re-run")
    return merged


def load_label_folder(folder: str | Path, scenario_ids: Sequence[str], n_egos: int = 1) -> LabelSet:
    """The finished label chunks ``folder/part_*.npz`` of an earlier `build_labels` run, as they are: nothing is
    simulated and no settings fingerprint is compared (the folder is only read, never emptied), so labels that
    took many minutes to simulate can be trained on again with other training settings.

    Args:
        folder: a label folder (e.g. ``OUT/labels/train`` of `seal fit objective`).
        scenario_ids: the scenarios the labels must be of, in order (each repeated ``n_egos`` times, as
            `build_labels` writes them).
        n_egos: label rows per scenario.
    """
    folder = Path(folder)
    parts = sorted(folder.glob("part_*.npz"))
    if not parts:
        raise FileNotFoundError(f"label folder {folder} has no part_*.npz chunks (build them with seal fit objective)")
    labels = LabelSet.concat([LabelSet.load(p) for p in parts])
    expected = [i for i in scenario_ids for _ in range(n_egos)]
    got = [str(i) for i in labels.scenario_ids]
    if got != expected:
        raise ValueError(f"label folder {folder}: its {len(got)} label rows are not the {len(expected)} expected rows "
                         "of this split (other scenarios, limit or egos); point --labels-from at the right folder")
    return labels
