"""``seal train``: train an SB3 ego in the closed loop with one adversary pipeline, or resume a killed run."""

from __future__ import annotations

import argparse

from seal.cli.args import CliError, add_plugin_option, add_set_option, positive_int
from seal.cli.tree import CommandTree

DEFAULT_CONFIG = "standard"
ALGOS = ("td3", "sac", "ppo", "reskill")
"""Ego algorithms (`seal.experiments.training.config.ALGOS`, repeated so ``seal --help`` stays light)."""


def overrides_from_args(args: argparse.Namespace) -> dict[str, object]:
    """Config overrides (dotted keys) from the named command-line options (``--set`` goes on top of them)."""
    over: dict[str, object] = {"pipeline": args.pipeline, "seed": args.seed, "algo": args.algo,
                               "dataset": args.dataset, "total_timesteps": args.steps, "n_envs": args.n_envs}
    if args.prior is not None:
        over["pipelines.cat.kwargs.prior"] = args.prior
        over["pipelines.seal.kwargs.prior"] = args.prior
        over["pipelines.steered.kwargs.prior"] = args.prior
    if args.steer is not None:
        over["pipelines.steered.kwargs.steer"] = args.steer
    if args.goose_model is not None:
        over["pipelines.goose.kwargs.model"] = args.goose_model
    if args.objective is not None:
        over["pipelines.seal.kwargs.objective"] = args.objective
    if args.skills is not None:
        over["pipelines.seal.kwargs.skills"] = args.skills
    if args.ego_skills is not None:
        over["hyperparams.reskill.skills"] = args.ego_skills
    return over


def _keyed_by_env(path: str) -> bool:
    """A zoo file keyed by env id (its algorithm must come from --algo or the config) rather than by algorithm."""
    from seal.core.config import read_yaml
    from seal.experiments.training.zoo import ZOO_ALGOS

    data = read_yaml(path)
    return isinstance(data, dict) and not all(str(k).lower() in ZOO_ALGOS for k in data)


def _overrides(args: argparse.Namespace) -> dict[str, object]:
    """The named options, on top of the settings of a ``--hyperparams`` zoo file."""
    overrides = {k: v for k, v in overrides_from_args(args).items() if v is not None}
    if args.hyperparams is None:
        return overrides
    from seal.experiments.training.config import read_train_section
    from seal.experiments.training.zoo import zoo_overrides

    algo = args.algo or (read_train_section(args.config or DEFAULT_CONFIG).get("algo") or "td3")
    zoo = zoo_overrides(args.hyperparams, algo if args.algo or _keyed_by_env(args.hyperparams) else None)
    return {**zoo, **overrides}


def cmd_train(args: argparse.Namespace) -> int:
    import json
    import signal
    import sys
    from pathlib import Path

    from seal.experiments.training.config import load_train_config
    from seal.experiments.training.state import RunFolderError, read_done
    from seal.experiments.training.train import run_torch_threads, train_run

    if (args.out is None) == (args.resume is None):
        raise CliError("give exactly one of --out RUN (a new run) or --resume RUN (continue a killed run)")
    if args.resume is not None:
        options = (("--config", args.config), ("--hyperparams", args.hyperparams), ("--pipeline", args.pipeline),
                   ("--seed", args.seed),
                   ("--set", args.set or None), ("--steps", args.steps), ("--algo", args.algo),
                   ("--dataset", args.dataset),
                   ("--n-envs", args.n_envs), ("--prior", args.prior), ("--goose-model", args.goose_model),
                   ("--objective", args.objective), ("--skills", args.skills), ("--ego-skills", args.ego_skills),
                   ("--steer", args.steer))
        given = [opt for opt, v in options if v is not None]
        if given:
            raise CliError(f"--resume continues with the run's recorded config.yaml; drop {', '.join(given)}")
        out, config = Path(args.resume), {}
    else:
        out = Path(args.out)
        config = load_train_config(args.config or DEFAULT_CONFIG, _overrides(args), sets=args.set)

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt  # `timeout` / a scheduler's SIGTERM: close the env workers, say how to resume

    signal.signal(signal.SIGTERM, interrupt)
    import torch

    torch.set_num_threads(run_torch_threads(config, out, args.resume is not None))
    try:
        train_run(config, out, resume=args.resume is not None, progress=not args.no_progress)
    except RunFolderError as exc:
        raise CliError(str(exc)) from None
    except KeyboardInterrupt:
        print(f"seal: interrupted; continue with `seal train --resume {out}` (from its last checkpoint)",
              file=sys.stderr)
        return 130
    done = read_done(out)
    print(json.dumps(done, indent=2) if args.json else f"run {out}: {done['steps']} env steps, {done['wall_s']} s")
    return 0


def register(tree: CommandTree) -> None:
    p = tree.top.add_parser(
        "train",
        help="train an ego (TD3 / SAC / PPO / ReSkill) against an adversary pipeline under CAT's curriculum",
        description="Train an ego policy with Stable-Baselines3 in the closed loop: a random train scenario per "
        "episode, perturbed with probability p(t) = min(1.8 t/T, 0.9) by the pipeline's generator (noadv: never; "
        "goose, cat, seal), one env worker per core, each keeping its scenarios' last K ego roll-outs. Writes a run "
        "folder: config.yaml (resolved), progress.csv + tb/ (TensorBoard) logs with episode success / crash / "
        "out-of-road rates, p(t) and generation time, eval/ (periodic evaluation on the Normal eval split), "
        "checkpoints/, final_model.zip and done.json. A killed run continues with --resume RUN and ends after the "
        "same number of steps; a finished run is never overwritten.",
    )
    p.add_argument("--config", default=None,
                   help="preset name (quick | standard | paper: experiments/configs/<name>.yaml), a YAML file with a "
                   "train: section, or a run folder (its recorded config.yaml: trains again as it did, with --set and "
                   f"the options below on top; give a new --out) (default {DEFAULT_CONFIG})")
    p.add_argument("--pipeline", default=None,
                   help="adversary pipeline: noadv, a pipeline of the config's train.pipelines (built-in: goose, cat, "
                   "seal, steered, cat-rcg, seal-rcg) or any generator name, e.g. one from --plugin (default: the "
                   "config's, cat)")
    add_plugin_option(p)
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the config's, 0)")
    p.add_argument("--out", default=None, help="new run folder (must be absent or empty)")
    p.add_argument("--resume", default=None, metavar="RUN", help="continue the unfinished run in RUN")
    p.add_argument("--algo", choices=ALGOS, default=None,
                   help="ego algorithm: td3 / sac / ppo (SB3) or reskill (a high-level agent choosing benign skills "
                   "every skill horizon plus a residual agent correcting each decoded action; needs --ego-skills; "
                   "the high-level learner: --set hyperparams.reskill.high_algo=td3|sac) (default td3)")
    p.add_argument("--dataset", default=None, help="dataset directory with train / eval splits (default: config)")
    p.add_argument("--steps", type=positive_int("--steps"), default=None, help="total env steps (default: config)")
    p.add_argument("--n-envs", type=positive_int("--n-envs"), default=None,
                   help="env worker processes (default: the config's, or every core)")
    p.add_argument("--prior", default=None, help="trajectory prior file for the cat, seal and steered pipelines")
    p.add_argument("--steer", default=None, help="steering folder (seal fit probes) for the steered pipeline")
    p.add_argument("--goose-model", default=None, help="GOOSE agent file for the goose pipeline")
    p.add_argument("--objective", default=None, help="SEAL objective network file for the seal pipeline")
    p.add_argument("--skills", default=None, help="SEAL skills folder (seal fit skills) for the seal pipeline")
    p.add_argument("--ego-skills", default=None,
                   help="skills folder the reskill ego draws its benign skills from (fit it with `seal fit skills "
                        "--preset ego`: a decoder that ignores the previous action, benign windows from DART "
                        "demonstrations of the heuristic driver)")
    p.add_argument("--hyperparams", default=None, metavar="FILE",
                   help="rl-baselines3-zoo hyperparameter file: keyed by env id (seal/Scenario-v0; the algorithm from "
                   "--algo or the config) or by algorithm (td3 / sac / ppo); n_timesteps, n_envs, policy_kwargs as "
                   "text or mapping, lin_<x> schedules; unsupported zoo keys (normalize, wrappers) are refused")
    add_set_option(p, "hyperparams.td3.learning_starts=500 (a train: key; settings of another algo are refused)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print done.json as JSON")
    p.set_defaults(func=cmd_train)
