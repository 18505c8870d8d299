"""``reuse: OTHER_OUT`` in a ``seal run`` preset (or ``--set reuse=OTHER_OUT``): take the data and the fitted models
of another run folder instead of making them again.

The expensive part of a comparison is often not the training but what comes before it (the decisive preset: ~3 h of
data and fits on this machine). A second comparison that changes only the egos (another ego algorithm, other
hyperparameters, more seeds) should train on the *same* data and generator models, both to save those hours and so
that the two comparisons differ only in what was changed (held-out pools the preset builds, ``eval.heldout``, too).
Each step of OTHER_OUT is taken only when its done-marker holds the parameter hash this preset would give it *in
that folder* (`seal.experiments.pipeline.steps`: the same options, the same dataset, the same models it depends on)
and its output exists; a fit whose own options or whose dependencies differ is made again in the new run folder,
on OTHER_OUT's dataset. So ``reuse`` never hands a model fitted with other options to a run that asks for different
ones.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from seal.experiments.pipeline.location import recorded_roots
from seal.experiments.pipeline.steps import Steps, data_steps, fit_steps, heldout_pool_steps


@dataclass(frozen=True)
class Reuse:
    """What `reuse_plan` found in the other run folder."""

    source: Path
    dataset: str | None
    """OTHER_OUT's dataset folder when all of its data steps match (None: the data is made anew)."""
    models: dict[str, str]
    """Model name -> its path in OTHER_OUT, for every fit that matches (dependencies included)."""
    refit: list[str]
    """Fits this preset needs that OTHER_OUT does not have with these options: made in the new run folder."""
    heldout: dict[str, str]
    """Held-out pool name -> its folder in OTHER_OUT, for every ``eval.heldout`` pool to build that OTHER_OUT built
    with the same options."""


def reuse_plan(config: Mapping[str, Any], source: Path) -> Reuse:
    """Which of ``config``'s data and fit steps are done in ``source`` with exactly the parameters ``config`` gives
    them there (module docstring). Raises ValueError when ``source`` is no ``seal run`` folder."""
    if not (source / "steps").is_dir():
        raise ValueError(f"reuse: {source} is not a seal run folder (no steps/ in it)")
    steps = Steps(source, recorded_roots(source))  # a moved source folder's older markers count too
    dataset, data_params, data = data_steps(config, source)
    data_done = all(steps.done(s.name, s.params) for s in data) and Path(dataset).is_dir()
    models, fits = fit_steps(config, source, dataset, data_params)
    reused: dict[str, str] = {}
    refit: list[str] = []
    for step in fits:  # dependencies first: a fit is reused only when every model it was made with is
        name = step.name.removeprefix("fit-")
        if (data_done and steps.done(step.name, step.params) and Path(models[name]).exists()
                and all(dep.removeprefix("fit-") in reused for dep in step.after)):
            reused[name] = models[name]
        else:
            refit.append(name)
    heldout = {name: pool[0].job["dataset"] for name, pool in heldout_pool_steps(config, source).items()
               if all(steps.done(s.name, s.params) for s in pool) and Path(pool[0].job["dataset"]).is_dir()}
    return Reuse(source, dataset if data_done else None, reused, refit, heldout)


def apply_reuse(config: dict[str, Any], plan: Reuse) -> dict[str, Any]:
    """``config`` with ``data.path`` and ``fit.NAME.path`` pointing at what ``plan`` reuses."""
    out = dict(config)
    if plan.dataset is not None:
        out["data"] = {"path": plan.dataset}
    fit = dict(out.get("fit") or {})
    for name, path in plan.models.items():
        fit[name] = {"path": path}
    out["fit"] = fit
    ev = dict(out.get("eval") or {})
    if plan.heldout and ev.get("heldout"):
        ev["heldout"] = [plan.heldout.get(str(e.get("name")), e) if isinstance(e, Mapping) else e
                         for e in ev["heldout"]]
        out["eval"] = ev
    return out


def describe(config: Mapping[str, Any], needed: list[str]) -> str:
    """One line for the log, from a config `apply_reuse` resolved: what is taken from ``config["reuse"]``, and which
    of the ``needed`` fits are made anew."""
    source = str(Path(str(config["reuse"])).expanduser().resolve())
    inside = lambda path: str(path or "").startswith(source + "/")  # noqa: E731
    fit = config.get("fit") or {}
    taken = [name for name in needed if inside((fit.get(name) or {}).get("path"))]
    data = ["data"] if inside((config.get("data") or {}).get("path")) else []
    refit = [name for name in needed if name not in taken]
    pools = [f"heldout/{Path(p).name}" for p in (config.get("eval") or {}).get("heldout") or []
             if isinstance(p, str) and inside(p)]
    return (f"reusing from {source}: {', '.join(data + taken + pools) or 'nothing'}"
            + (f"; fitted here: {', '.join(refit)}" if refit else ""))
