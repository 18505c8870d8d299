"""Uncertainty of the ego comparison with rliable's estimators (Agarwal et al. 2021, "Deep RL at the edge of the
statistical precipice"), resampled the way this evaluation's data are laid out.

What the estimators see. An evaluation episode is a 0/1 outcome (success, crash, out of road) of one ego (a seed of
a training pipeline) on one scenario of a setting. Per (pipeline, setting) the scores are the matrix
``scenarios x seeds`` of those outcomes (only the scenarios every seed played, so the matrix is rectangular):

* **mean**: the rate over all its episodes, which is the mean of the seeds' rates (every seed plays the same
  scenarios).
* **IQM**: rliable's interquartile mean (`rliable.metrics.aggregate_iqm`, a 25 % trimmed mean; `iqm_columns`
  computes the same numbers faster) of the *seeds' rates*, so one outlying seed does not move it (with 4 seeds:
  the mean of the middle two). The IQM of the 0/1 episodes themselves would be ``clip((p - 0.25) / 0.5, 0, 1)`` of
  the mean ``p``: a clipped rescaling that carries nothing the mean does not.
* **95 % intervals** of the mean and the IQM: the crossed ("pigeonhole", Owen 2007) bootstrap, `crossed_bootstrap`:
  each resample draws the seeds with replacement and, once for all of them, the scenarios, because every seed plays
  the same scenarios (seeds and scenarios are crossed, and a hard scenario is hard for every seed). rliable's
  stratified bootstrap (`rliable.library.get_interval_estimates` with ``task_bootstrap``, tasks = seeds, runs =
  scenarios) redraws the scenarios independently within each drawn seed, as if each seed had played its own
  scenarios, which divides the scenario-to-scenario variance by the number of seeds. Measured on the fifth decisive
  run's episodes: random half-against-half splits of one pipeline's egos and scenarios in one setting (TD3: 4 seeds
  x 150 scenarios against the other 4 seeds x the other 150; ReSkill: 2 x 150; no true difference, 1,260 splits
  each) differed by more than their two intervals allow (|z| > 1.96) in 14.4 / 13.8 % (TD3 / ReSkill) with rliable's
  stratified bootstrap, 3.7 / 4.0 % with the crossed one, 32.5 / 76.7 % with the seeds alone resampled (nominal 5
  %). So the crossed interval is the one that holds on scenarios the evaluation has not seen; rliable's stays in
  ``ego_ci.csv`` as ``stratified_low`` / ``stratified_high`` for comparison.
* **probability of improvement** P(X > Y) (`rliable.metrics.probability_of_improvement`): per setting the
  Mann-Whitney statistic of the two pipelines' per-seed success rates over all seed pairs (ties count one half),
  averaged over the settings both were evaluated on. Its interval resamples each pipeline's seeds as whole egos
  (arch's independent-samples bootstrap, which rliable's own is built on, over the rows of ``seeds x settings``): a
  drawn seed brings its rate in every setting, because one ego plays them all. rliable's stratified bootstrap
  redraws the seeds per setting (right for Atari, where every game is its own training run), which here counts
  one ego's 10 settings as 10 independent seeds: on the decisive store CAT > No-Adv (ReSkill) came out
  0.71 [0.60-0.83] that way, all of it one weak No-Adv seed, and 0.71 [0.44-0.94] with whole egos.
  ``P(Y > X) = 1 - P(X > Y)`` exactly, resamples included, so each unordered pair is bootstrapped once.
* **permutation test** of P (`poi_permutation_p`): the two pipelines' egos pooled and split again into groups of
  the same sizes (whole egos, every split when there are at most `N_PERM`), two-sided. The percentile bootstrap
  over 4 seeds a side covers too little: on the fifth decisive run's TD3 egos (8 seeds a pipeline), splitting each
  pipeline's own seeds 4 against 4 (35 splits x 7 pipelines, no true difference) put P's interval on one side of
  0.5 in 31 of 245 splits (12.7 %, against the 5 % the interval promises), while a permutation test is exact by
  construction. A pipeline is said to beat another (`poi_verdict`) only when both agree.

rliable draws from NumPy's global generator; `seeded` seeds it for each estimate and restores it afterwards, so
the intervals are reproducible and the caller's random stream is untouched. Egos with another algorithm are
labelled apart by `seal.experiments.report.grouping` before they get here and are only compared within their algorithm.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Collection, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from seal.experiments.report.compare import EGO_METRICS, ordered_pipelines, ordered_settings, setting_label
from seal.experiments.report.grouping import algo_of, comparable, is_trained

N_BOOT = 2000
"""Bootstrap resamples of the mean / IQM intervals."""
N_BOOT_POI = 1000
"""Bootstrap resamples of the probability of improvement (each resample is one `pairwise_improvement`, ~20 us)."""
CONFIDENCE = 0.95
N_PERM = 10_000
"""Most relabellings of the permutation test of P: every split of the pooled egos when there are at most this many
(4 + 4 seeds: 70), else this many random ones."""
ALPHA = 0.05
"""Level of the permutation test behind a verdict. Its smallest p with n seeds a side is 2 / C(2n, n): 0.33 with 2,
0.10 with 3, 0.029 with 4, so a verdict needs 4 seeds a side or more."""
MIN_SEEDS_FOR_POI = 3
"""Seeds a side below which no verdict rests on a probability of improvement: it compares seeds, and with one seed
a side its bootstrap interval has zero width whatever the data (the first page and the claims say so instead)."""


def enough_seeds(poi_row: Mapping[str, Any]) -> bool:
    """Whether an `improvement_table` row has `MIN_SEEDS_FOR_POI` seeds on both sides."""
    return min(int(poi_row["seeds"]), int(poi_row["reference_seeds"])) >= MIN_SEEDS_FOR_POI


@contextmanager
def seeded(seed: int) -> Iterator[None]:
    """rliable samples from ``np.random``'s global state: seed it for one estimate, then put it back."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


@dataclass(frozen=True)
class ScoreMatrix:
    """The episodes of one (pipeline, setting): ``values [scenarios, seeds, metrics]`` 0/1 outcomes of
    ``EGO_METRICS`` for the scenarios every seed played (``scenario_ids``, sorted) and the seeds' ``runs``."""

    scenario_ids: tuple[str, ...]
    runs: tuple[str, ...]
    values: np.ndarray

    def rates(self, metric: str = "success") -> np.ndarray:
        """Each seed's rate of ``metric`` over the scenarios, ``[seeds]``."""
        return self.values[:, :, EGO_METRICS.index(metric)].mean(axis=0)


def score_matrices(rows: Sequence[Mapping[str, Any]]) -> dict[tuple[str, str], ScoreMatrix]:
    """``{(pipeline, setting): ScoreMatrix}`` from the store's episode rows (keys ``pipeline``, ``setting``,
    ``run``, ``scenario_id`` and the metrics); a scenario some seed has not played yet is left out of its cell."""
    cells: dict[tuple[str, str], dict[str, dict[str, Mapping[str, Any]]]] = {}
    for r in rows:
        cells.setdefault((r["pipeline"], r["setting"]), {}).setdefault(r["run"], {})[str(r["scenario_id"])] = r
    out = {}
    for key, by_run in cells.items():
        runs = sorted(by_run)
        common = sorted(set.intersection(*(set(v) for v in by_run.values())))
        values = np.array([[[float(bool(by_run[run][sid][m])) for m in EGO_METRICS] for run in runs]
                           for sid in common], dtype=np.float64).reshape(len(common), len(runs), len(EGO_METRICS))
        out[key] = ScoreMatrix(tuple(common), tuple(runs), values)
    return out


def paired_outcomes(x: ScoreMatrix, y: ScoreMatrix, metric: str = "success") -> tuple[np.ndarray, np.ndarray]:
    """The ``metric`` outcomes ``[scenarios, seeds]`` of both cells on the scenarios both played (sorted ids), in
    the same order."""
    common = sorted(set(x.scenario_ids) & set(y.scenario_ids))
    xi, yi = ({s: i for i, s in enumerate(m.scenario_ids)} for m in (x, y))
    j = EGO_METRICS.index(metric)
    return (x.values[[xi[s] for s in common], :, j].astype(np.float64),
            y.values[[yi[s] for s in common], :, j].astype(np.float64))


def iqm_columns(scores: np.ndarray) -> np.ndarray:
    """rliable's IQM (`rliable.metrics.aggregate_iqm`: scipy's ``trim_mean(proportiontocut=0.25)``) of each column
    of ``scores [runs, columns]``: sort, drop ``int(0.25 runs)`` from each end, average. Written out because the
    bootstrap calls it thousands of times and scipy's call costs ~1.2 ms against ~0.02 ms here; the tests check it
    equals rliable's."""
    cut = int(0.25 * scores.shape[0])
    return np.sort(scores, axis=0)[cut:scores.shape[0] - cut].mean(axis=0)


def scenario_draws(n_scenarios: int, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """``[n_boot, n_scenarios]`` float counts: how often each scenario is drawn (with replacement) per resample."""
    p = np.full(n_scenarios, 1.0 / n_scenarios)
    return rng.multinomial(n_scenarios, p, size=n_boot).astype(np.float64)


def drawn_seed_rates(values: np.ndarray, counts: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``[n_boot, seeds, ...]``: the rates of seeds drawn with replacement (``values [scenarios, seeds, ...]``), each
    on the scenarios ``counts`` (`scenario_draws`) drew for that resample, the same ones for every seed."""
    n_scen, n_seeds = values.shape[:2]
    rates = np.tensordot(counts, values, axes=(1, 0)) / n_scen  # [B, seeds, ...]
    drawn = rng.integers(0, n_seeds, size=(counts.shape[0], n_seeds))
    return np.take_along_axis(rates, drawn.reshape(drawn.shape + (1,) * (rates.ndim - 2)), axis=1)


def crossed_bootstrap(values: np.ndarray, n_boot: int = N_BOOT, seed: int = 0) -> np.ndarray:
    """``[n_boot, 2, metrics]`` resampled (mean, IQM over seeds) of ``values [scenarios, seeds, metrics]`` under the
    crossed (pigeonhole) bootstrap: each resample draws the seeds with replacement and, once for all of them, the
    scenarios with replacement (module docstring). The IQM is rliable's (`iqm_columns`)."""
    rng = np.random.default_rng(seed)
    rates = drawn_seed_rates(values, scenario_draws(values.shape[0], n_boot, rng), rng)  # [B, seeds, metrics]
    n_seeds = values.shape[1]
    cut = int(0.25 * n_seeds)
    iqm = np.sort(rates, axis=1)[:, cut:n_seeds - cut].mean(axis=1)
    return np.stack([rates.mean(axis=1), iqm], axis=1)


def mean_iqm_intervals(matrix: ScoreMatrix, n_boot: int = N_BOOT, seed: int = 0) -> dict[str, dict[str, float]]:
    """Per metric ``{mean, mean_low, mean_high, iqm, iqm_low, iqm_high}`` (rates in [0, 1]) with the crossed
    bootstrap over seeds and scenarios (`crossed_bootstrap`, percentile intervals), and ``stratified_low`` /
    ``stratified_high``, the mean's interval from rliable's stratified bootstrap, which covers too little here
    (module docstring); NaNs when the matrix has no scenario."""
    from rliable import library as rly

    keys = ("mean", "mean_low", "mean_high", "iqm", "iqm_low", "iqm_high", "stratified_low", "stratified_high")
    if matrix.values.shape[0] == 0:
        return {m: dict.fromkeys(keys, math.nan) for m in EGO_METRICS}
    rates = matrix.values.mean(axis=0)  # [seeds, metrics]
    points = np.stack([rates.mean(axis=0), iqm_columns(rates)])  # [2, metrics]
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(crossed_bootstrap(matrix.values, n_boot, seed), [tail, 100 - tail], axis=0)
    with seeded(seed):
        _, strat = rly.get_interval_estimates(
            {"x": matrix.values}, lambda v: v.mean(axis=(0, 1)), task_bootstrap=True, reps=n_boot,
            confidence_interval_size=CONFIDENCE)
    out = {}
    for j, m in enumerate(EGO_METRICS):
        row = {}
        for i, stat in enumerate(("mean", "iqm")):
            row.update({stat: float(points[i, j]), f"{stat}_low": float(low[i, j]), f"{stat}_high": float(high[i, j])})
        row.update(stratified_low=float(strat["x"][0, j]), stratified_high=float(strat["x"][1, j]))
        out[m] = row
    return out


def ego_ci_table(rows: Sequence[Mapping[str, Any]], n_boot: int = N_BOOT, seed: int = 0) -> list[dict[str, Any]]:
    """One row per (pipeline, setting, metric): ``seeds``, ``scenarios`` (per seed), ``mean`` with ``ci_low`` /
    ``ci_high``, ``iqm`` with ``iqm_low`` / ``iqm_high`` (rates in [0, 1]), ``half_width`` (of the mean's
    interval) and ``seed_min`` / ``seed_max`` (the lowest and highest seed's rate: how much of the width the seeds
    themselves make)."""
    matrices = score_matrices(rows)
    table = []
    for pipeline in ordered_pipelines(p for p, _ in matrices):
        for setting in ordered_settings(s for p, s in matrices if p == pipeline):
            m = matrices[(pipeline, setting)]
            est = mean_iqm_intervals(m, n_boot, seed)
            for metric in EGO_METRICS:
                e = est[metric]
                table.append({
                    "pipeline": pipeline, "setting": setting_label(setting), "metric": metric,
                    "seeds": len(m.runs), "scenarios": len(m.scenario_ids),
                    "mean": e["mean"], "ci_low": e["mean_low"], "ci_high": e["mean_high"],
                    "half_width": (e["mean_high"] - e["mean_low"]) / 2,
                    "iqm": e["iqm"], "iqm_low": e["iqm_low"], "iqm_high": e["iqm_high"],
                    "stratified_low": e["stratified_low"], "stratified_high": e["stratified_high"],
                    **_seed_span(m, metric),
                })
    return table


def _seed_span(matrix: ScoreMatrix, metric: str) -> dict[str, float]:
    rates = matrix.rates(metric) if matrix.values.size else np.array([math.nan])
    return {"seed_min": float(rates.min()), "seed_max": float(rates.max())}


def poi_interval(x: Sequence[np.ndarray], y: Sequence[np.ndarray], n_boot: int = N_BOOT_POI, seed: int = 0
                 ) -> tuple[float, float, float]:
    """``(P(X > Y), low, high)``: rliable's average probability of improvement over tasks of the per-seed scores
    ``x[t] [seeds_x]``, ``y[t] [seeds_y]`` (seed ``i`` of a side is the same ego in every task), with a percentile
    bootstrap interval that resamples each side's seeds jointly across tasks (module docstring)."""
    from arch.bootstrap import IndependentSamplesBootstrap
    from rliable import metrics

    sx, sy = _seeds_by_task(x), _seeds_by_task(y)
    point = float(metrics.probability_of_improvement(sx, sy))
    bootstrap = IndependentSamplesBootstrap(sx, sy, seed=np.random.default_rng(seed))
    ci = bootstrap.conf_int(lambda a, b: np.array([pairwise_improvement(a, b)]), reps=n_boot,
                            method="percentile", size=CONFIDENCE).ravel()
    return point, float(ci[0]), float(ci[1])


def _seeds_by_task(scores: Sequence[np.ndarray]) -> np.ndarray:
    """``[seeds, tasks]`` float64 from the per-task seed scores ``scores[t] [seeds]`` (rliable's layout)."""
    return np.stack([np.asarray(v, np.float64) for v in scores], 1)


def pairwise_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """rliable's `probability_of_improvement` of ``scores_x [runs_x, tasks]`` over ``scores_y [runs_y, tasks]``
    (per task the Mann-Whitney U of x over y divided by ``runs_x * runs_y``: the share of run pairs where x is
    higher, ties counting one half; averaged over tasks), with every pair compared at once. Written out because
    the bootstrap calls it a thousand times per interval (the permutation test up to `N_PERM` times) and rliable
    calls scipy's test once per task (1-5 ms each: 7.3 of the 9.6 min `seal compare` took on the fifth decisive
    run's store); the tests check it equals rliable's."""
    diff = scores_x[:, None, :] - scores_y[None, :, :]  # [runs_x, runs_y, tasks]
    return float(((diff > 0) + 0.5 * (diff == 0)).mean())


def poi_permutation_p(x: Sequence[np.ndarray], y: Sequence[np.ndarray], n_perm: int = N_PERM, seed: int = 0
                      ) -> float:
    """Two-sided permutation p-value of ``P(X > Y) = 0.5`` for the per-seed scores ``x[t] [seeds_x]``, ``y[t]
    [seeds_y]`` of `poi_interval`: the share of splits of the pooled egos (whole egos, every task kept together)
    into groups of the two sizes whose ``|P - 0.5|`` is at least the observed one. Exact (every split, the observed
    one included) when there are at most ``n_perm``; else ``n_perm`` random splits, ``(hits + 1) / (n_perm + 1)``."""
    sx, sy = _seeds_by_task(x), _seeds_by_task(y)
    pooled, n, total = np.concatenate([sx, sy]), len(sx), len(sx) + len(sy)
    observed = abs(pairwise_improvement(sx, sy) - 0.5) - 1e-12  # float slack: equal statistics count as hits
    exact = math.comb(total, n) <= n_perm
    rng = np.random.default_rng(seed)
    splits = (itertools.combinations(range(total), n) if exact
              else (rng.permutation(total)[:n] for _ in range(n_perm)))
    hits = count = 0
    for chosen in splits:
        mask = np.zeros(total, dtype=bool)
        mask[list(chosen)] = True
        hits += abs(pairwise_improvement(pooled[mask], pooled[~mask]) - 0.5) >= observed
        count += 1
    return hits / count if exact else (hits + 1) / (count + 1)


def poi_verdict(row: Mapping[str, Any]) -> str:
    """``holds`` (the row's pipeline beats its reference), ``reversed`` or ``not shown`` for an `improvement_table`
    row: holds / reversed need `MIN_SEEDS_FOR_POI` seeds a side, P's bootstrap interval on one side of 0.5 and the
    permutation test's p below `ALPHA` (module docstring: the interval alone covers too little with few seeds)."""
    if not enough_seeds(row) or not row["p_perm"] < ALPHA:
        return "not shown"
    return "holds" if row["ci_low"] > 0.5 else "reversed" if row["ci_high"] < 0.5 else "not shown"


def _same_egos(matrices: Mapping[tuple[str, str], ScoreMatrix], pipeline: str, settings: Sequence[str]) -> bool:
    """Whether ``pipeline`` has the same seeds (run folders, sorted) in every setting: the bootstrap draws whole
    egos, so seed ``i`` must be one ego across the settings."""
    return len({matrices[(pipeline, s)].runs for s in settings}) == 1


def improvement_table(rows: Sequence[Mapping[str, Any]], n_boot: int = N_BOOT_POI, seed: int = 0,
                      per_setting: bool = False, only: Collection[tuple[str, str, str]] | None = None
                      ) -> list[dict[str, Any]]:
    """Probability that ``pipeline``'s ego beats ``reference``'s in success rate, for every ordered pair of trained
    pipelines of the same algorithm: ``p_improvement`` with ``ci_low`` / ``ci_high``, averaged over the ``settings``
    (count) both were evaluated on with the same seeds (``per_setting``: one row per pair and setting, with
    ``setting``; ``only``: just these ``(pipeline, reference, setting label)`` triples, either order), and the
    seeds on each side, and ``p_perm`` (`poi_permutation_p`, the same for both orders). Pairs evaluated on no
    common setting are left out."""
    matrices = score_matrices(rows)
    pipelines = [p for p in ordered_pipelines(p for p, _ in matrices) if is_trained(p)]
    wanted = None if only is None else {(a, b, s) for x, y, s in only for a, b in ((x, y), (y, x))}
    table = []
    for i, a in enumerate(pipelines):
        for b in pipelines[i + 1:]:
            if not comparable(a, b):
                continue
            common = [s for s in ordered_settings(s for p, s in matrices if p == a) if (b, s) in matrices
                      and matrices[(a, s)].scenario_ids and matrices[(b, s)].scenario_ids]
            groups = ([[s] for s in common if wanted is None or (a, b, setting_label(s)) in wanted]
                      if per_setting else [common])
            for settings in groups:
                if not settings or not (_same_egos(matrices, a, settings) and _same_egos(matrices, b, settings)):
                    continue
                xs, ys = [matrices[(a, s)].rates() for s in settings], [matrices[(b, s)].rates() for s in settings]
                p, lo, hi = poi_interval(xs, ys, n_boot, seed)
                p_perm = poi_permutation_p(xs, ys, seed=seed)
                base = {"settings": len(settings), **({"setting": setting_label(settings[0])} if per_setting else {})}
                na, nb = len(matrices[(a, settings[0])].runs), len(matrices[(b, settings[0])].runs)
                table.append({"pipeline": a, "reference": b, **base, "seeds": na, "reference_seeds": nb,
                              "p_improvement": p, "ci_low": lo, "ci_high": hi, "p_perm": p_perm})
                table.append({"pipeline": b, "reference": a, **base, "seeds": nb, "reference_seeds": na,
                              "p_improvement": 1 - p, "ci_low": 1 - hi, "ci_high": 1 - lo, "p_perm": p_perm})
    return table


def ci_cell(point: float, low: float, high: float, scale: float = 100.0, digits: int = 1) -> str:
    """``estimate [low-high]`` of ``scale`` times the values, ``-`` for NaN, ``[no interval]`` without bounds."""
    if not math.isfinite(point):
        return "-"
    if not (math.isfinite(low) and math.isfinite(high)):
        return f"{scale * point:.{digits}f} [no interval]"
    return f"{scale * point:.{digits}f} [{scale * low:.{digits}f}-{scale * high:.{digits}f}]"


def ci_markdown(table: Sequence[Mapping[str, Any]], metric: str = "success", statistic: str = "mean") -> str:
    """Pipelines x settings, cells ``estimate % [low-high]`` of ``metric``'s ``statistic`` (``mean`` or ``iqm``)."""
    rows = [r for r in table if r["metric"] == metric]
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    low, high = ("ci_low", "ci_high") if statistic == "mean" else ("iqm_low", "iqm_high")
    out = ["| pipeline | seeds | " + " | ".join(settings) + " |", "|---|---:|" + "---:|" * len(settings)]
    for pipeline in dict.fromkeys(r["pipeline"] for r in rows):
        cells = {r["setting"]: r for r in rows if r["pipeline"] == pipeline}
        seeds = max(r["seeds"] for r in cells.values())
        out.append(f"| {pipeline} | {seeds} | " + " | ".join(
            ci_cell(c[statistic], c[low], c[high]) if (c := cells.get(s)) else "-" for s in settings) + " |")
    return "\n".join(out) + "\n"


def improvement_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The averaged probabilities of improvement as a matrix per ego algorithm: row X, column Y, cell
    ``P(X > Y) [low-high] p=...`` (the permutation test's p)."""
    rows = [r for r in table if "setting" not in r]
    cells = {(r["pipeline"], r["reference"]): r for r in rows}
    out = []
    for algo in dict.fromkeys(algo_of(p) for p in ordered_pipelines({r["pipeline"] for r in rows})):
        names = ordered_pipelines({r["pipeline"] for r in rows if algo_of(r["pipeline"]) == algo})
        out += ["| P(row > column) | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
        for a in names:
            out.append(f"| {a} | " + " | ".join(
                f"{ci_cell(c['p_improvement'], c['ci_low'], c['ci_high'], 1.0, 2)} p={c['p_perm']:.2f}"
                if (c := cells.get((a, b))) else "-"
                for b in names) + " |")
        out.append("")
    return "\n".join(out)


def seed_profile_table(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per trained pipeline and seed: the seed's success rate averaged over the ``settings`` (count) that every seed
    of the pipeline played. The probability of improvement over all settings compares these egos whole, so a seed
    far from its siblings (e.g. a degenerate learner) moves every comparison of its pipeline; this shows it."""
    matrices = score_matrices(rows)
    table = []
    for pipeline in ordered_pipelines(p for p, _ in matrices):
        settings = [s for p, s in matrices if p == pipeline and matrices[(p, s)].scenario_ids]
        if not is_trained(pipeline) or not settings:
            continue
        runs = sorted(set.intersection(*(set(matrices[(pipeline, s)].runs) for s in settings)))
        for run in runs:
            rates = [matrices[(pipeline, s)].rates()[matrices[(pipeline, s)].runs.index(run)] for s in settings]
            table.append({"pipeline": pipeline, "run": run, "settings": len(settings),
                          "success": float(np.mean(rates))})
    return table


def _seed_label(run: str) -> str:
    """``s3`` for a run folder named ``...-s3``, else the folder name."""
    name = run.rstrip("/").rsplit("/", 1)[-1]
    tail = name.rsplit("-", 1)[-1]
    return tail if tail[:1] == "s" and tail[1:].isdigit() else name


def seed_profile_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """One row per pipeline: each seed's success over the settings (%, in seed order) and the spread (points)."""
    by_pipeline: dict[str, list[Mapping[str, Any]]] = {}
    for r in table:
        by_pipeline.setdefault(r["pipeline"], []).append(r)
    out = ["| pipeline | settings | each seed's success over the settings (%) | spread (points) |",
           "|---|---:|---|---:|"]
    for pipeline, seeds in by_pipeline.items():
        values = [100 * s["success"] for s in seeds]
        cells = ", ".join(f"{_seed_label(s['run'])} {v:.1f}" for s, v in zip(seeds, values, strict=True))
        out.append(f"| {pipeline} | {seeds[0]['settings']} | {cells} | {max(values) - min(values):.1f} |")
    return "\n".join(out) + "\n"
