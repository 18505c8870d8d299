"""Normal / Hard splits from the SafeShift scores (thesis 3.4.1 and 6.4: hold out the top 20 %), by group.

Two rules pick the scenes eligible for Hard (``hard_by``), both on one score variant (GT, FE, AS or AC):

* ``"pair"`` (default; the SEAL chapter's WOMD-SafeShift-Hard): the trajectory scores of a scene's interacting
  pair are both above the ``hard_quantile`` quantile of all interacting agents' trajectory scores of the pool.
  In a Hard scene the higher-scoring agent of the pair becomes the ego and the lower-scoring one the
  adversary; the roles are stored in the manifest (``"roles"``) and every `Dataset.load` applies them.
* ``"scene"``: the scene score is above the ``hard_quantile`` quantile of the pool's scene scores.

Every scenario belongs to a group: the recording or traffic run it was cut from (`seal.core.scenario.group_of`).
Whole groups are dealt to the splits, never a group to two of them: a seeded shuffle of the groups that hold an
eligible scene fills Hard with their eligible scenes; a seeded shuffle of the remaining groups fills Normal eval,
then Normal train, with their non-eligible scenes. The last group a split takes may give only part of its
scenes (in dataset order); the rest of that group is used by no split. The overlap check (groups shared between
splits, always 0) is computed from the result and recorded.

The splits go to the manifest's ``"splits"`` (``{"train": [...], "eval": [...], "hard": [...]}``, ids in dataset
order), the parameters with the threshold and the group check to ``"split_params"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.dataset import Dataset, DatasetError
from seal.core.scenario import GroupError, Scenario, group_of
from seal.scoring.scores import VARIANTS
from seal.scoring.split_stats import split_close_calls
from seal.scoring.store import ScoreTable, load_scores

HARD_BY = ("pair", "scene")
SPLIT_NAMES = ("train", "eval", "hard")


class SplitError(DatasetError):
    """The pool cannot provide the requested splits; the message names the option to change."""


def make_splits(
    dataset_dir: str | Path,
    hard_quantile: float = 0.8,
    n_train: int = 400,
    n_eval: int = 100,
    n_hard: int = 100,
    seed: int = 42,
    score: str = "ac",
    hard_by: str = "pair",
) -> dict[str, Any]:
    """Draw and record the splits (see the module docstring).

    Returns the counts per split, ``hard_by``, ``shared_groups`` (0), groups per split, the threshold, mean
    scores, the number of Hard scenes whose roles were exchanged, and logged (GT) and counterfactual (AC)
    close-call and collision rates per split.
    """
    root = Path(dataset_dir)
    variant = score
    _check_options(hard_quantile, n_train, n_eval, n_hard, variant, hard_by)
    ds = Dataset.open(root)
    table = load_scores(root)
    if len(table) != len(ds):  # scores of another build of this directory
        raise SplitError(
            f"{root}: the scores cover {len(table)} scenes but the dataset has {len(ds)}; "
            f"run `seal data score {root}` again"
        )
    scenarios = ds.load()
    if [s.scenario_id for s in scenarios] != table.scenario_ids:
        raise SplitError(f"{root}: the scores are of other scenarios; run `seal data score {root}` again")
    try:
        groups = [group_of(s) for s in scenarios]
    except GroupError as exc:
        raise SplitError(f"{root}: {exc}") from None

    if hard_by == "pair":
        eligible, threshold, rank_score, ranked_pairs = _pair_rule(table, scenarios, hard_quantile, variant)
    else:
        rank_score = table.scene(variant).astype(np.float64)
        threshold = float(np.quantile(rank_score, hard_quantile))
        eligible, ranked_pairs = rank_score > threshold, {}
    rows = deal_groups(groups, eligible, {"hard": n_hard, "eval": n_eval, "train": n_train}, seed)
    shortfall = {name: want for name, want in (("hard", n_hard), ("eval", n_eval), ("train", n_train))
                 if len(rows[name]) < want}
    if shortfall:
        raise SplitError(_shortfall_message(shortfall, rows, eligible, groups, hard_quantile, variant, hard_by))

    ids = [s.scenario_id for s in scenarios]
    splits = {name: [ids[k] for k in rows[name]] for name in SPLIT_NAMES}
    group_sets = {name: {groups[k] for k in rows[name]} for name in SPLIT_NAMES}
    shared = shared_groups(group_sets)
    roles = {ids[k]: list(ranked_pairs[k]) for k in rows["hard"]} if hard_by == "pair" else {}
    params = {
        "method": "safeshift",
        "hard_by": hard_by,
        "score": variant,
        "hard_quantile": hard_quantile,
        "threshold": threshold,
        "n_train": n_train,
        "n_eval": n_eval,
        "n_hard": n_hard,
        "seed": seed,
        "scores_sha256": ds.manifest["scores"]["sha256"],
        "groups": {name: len(group_sets[name]) for name in SPLIT_NAMES},
        "shared_groups": shared,
    }
    ds.update_manifest(splits=splits, split_params=params, roles=roles)
    members = {name: [ds.apply_roles(scenarios[k]) for k in rows[name]] for name in SPLIT_NAMES}
    return {
        "hard_by": hard_by,
        "score": variant,
        "shared_groups": shared,
        **{name: len(splits[name]) for name in SPLIT_NAMES},
        "groups": params["groups"],
        "threshold": threshold,
        "roles_exchanged": sum(ranked_pairs[k][0] != scenarios[k].ego_id for k in rows["hard"] if k in ranked_pairs),
        "mean_score": {name: float(np.mean(rank_score[rows[name]])) if rows[name] else float("nan")
                       for name in SPLIT_NAMES},
        "close_calls": {name: split_close_calls(members[name]) for name in SPLIT_NAMES},
        "params": params,
    }


def _check_options(hard_quantile: float, n_train: int, n_eval: int, n_hard: int, variant: str, hard_by: str) -> None:
    if not 0.0 < hard_quantile < 1.0:
        raise SplitError(f"--hard-quantile must be in (0, 1), got {hard_quantile}")
    for name, value in (("--n-train", n_train), ("--n-eval", n_eval), ("--n-hard", n_hard)):
        if value < 0:
            raise SplitError(f"{name} must be >= 0, got {value}")
    if hard_by not in HARD_BY:
        raise SplitError(f"--hard-by must be one of {', '.join(HARD_BY)}, got {hard_by!r}")
    if variant not in VARIANTS:
        raise SplitError(f"--score must be one of {', '.join(VARIANTS)}, got {variant!r}")


def _pair_rule(
    table: ScoreTable, scenarios: Sequence[Scenario], hard_quantile: float, variant: str
) -> tuple[np.ndarray, float, np.ndarray, dict[int, tuple[int, int]]]:
    """Eligibility ``[N]``, threshold, per-scene score ``[N]`` (the pair's smaller trajectory score) and, per
    scene, ``(higher-scoring agent id, lower-scoring agent id)`` of its interacting pair."""
    traj = table.arrays[f"traj_{variant}"].astype(np.float64)
    agent_ids = table.arrays["agent_ids"]
    pair_scores = np.zeros((len(scenarios), 2))
    ranked: dict[int, tuple[int, int]] = {}
    for k, s in enumerate(scenarios):
        rows = table.agents(k)
        by_id = dict(zip(agent_ids[rows].tolist(), traj[rows].tolist(), strict=True))
        first, second = by_id[s.ego_id], by_id[s.adv_id]
        pair_scores[k] = first, second
        # Ties keep the built roles.
        ranked[k] = (s.ego_id, s.adv_id) if first >= second else (s.adv_id, s.ego_id)
    threshold = float(np.quantile(pair_scores.ravel(), hard_quantile))
    low = pair_scores.min(axis=1)
    return low > threshold, threshold, low, ranked


def deal_groups(groups: Sequence[str], eligible: np.ndarray, want: dict[str, int], seed: int) -> dict[str, list[int]]:
    """Scene rows per split, whole groups at a time (see the module docstring).

    Args:
        groups: ``[N]`` group of every scene.
        eligible: ``[N]`` bool, the scene may go to Hard (and only there).
        want: scenes wanted for ``"hard"``, ``"eval"`` and ``"train"``.
        seed: seed of the group shuffles.

    Returns ``{split: rows in dataset order}``; a split gets fewer rows than wanted only if the groups run out.
    """
    members: dict[str, list[int]] = {}
    for k, g in enumerate(groups):
        members.setdefault(g, []).append(k)
    names = sorted(members)  # sorted: the shuffle must not depend on dataset order within the pool
    rng = np.random.default_rng(seed)
    hard_groups = [names[i] for i in rng.permutation(len(names)) if any(eligible[k] for k in members[names[i]])]
    out: dict[str, list[int]] = {"hard": [], "eval": [], "train": []}
    used: set[str] = set()
    for g in hard_groups:
        if len(out["hard"]) >= want["hard"]:
            break
        out["hard"].extend([k for k in members[g] if eligible[k]][: want["hard"] - len(out["hard"])])
        used.add(g)
    rest = [names[i] for i in rng.permutation(len(names)) if names[i] not in used]
    split = iter(("eval", "train"))
    name = next(split)
    for g in rest:
        while len(out[name]) >= want[name]:
            name = next(split, "")
            if not name:
                break
        if not name:
            break
        out[name].extend([k for k in members[g] if not eligible[k]][: want[name] - len(out[name])])
    return {name: sorted(rows) for name, rows in out.items()}


def shared_groups(group_sets: dict[str, set[str]]) -> int:
    """Number of groups that appear in more than one split."""
    seen: dict[str, int] = {}
    for gs in group_sets.values():
        for g in gs:
            seen[g] = seen.get(g, 0) + 1
    return sum(1 for n in seen.values() if n > 1)


def _shortfall_message(
    shortfall: dict[str, int], rows: dict[str, list[int]], eligible: np.ndarray, groups: Sequence[str],
    hard_quantile: float, variant: str, hard_by: str,
) -> str:
    name, want = next(iter(shortfall.items()))
    option = {"hard": "--n-hard", "eval": "--n-eval", "train": "--n-train"}[name]
    n_groups = len(set(groups))
    if name == "hard":
        return (
            f"only {int(eligible.sum())} scenes qualify for Hard ({hard_by} rule, {variant.upper()} score above "
            f"the {hard_quantile:g} quantile) and {len(rows['hard'])} could be used, {option} asks for {want}: "
            "lower --n-hard or --hard-quantile, or generate a larger pool"
        )
    return (
        f"the {n_groups} groups (recordings / traffic runs) left {len(rows[name])} Normal scenes for {name}, "
        f"{option} asks for {want}; windows of one group never go to two splits: lower --n-train / --n-eval "
        "or --n-hard, raise --hard-quantile, or generate / import a larger pool"
    )
