"""``seal fit skills``: SEAL's skill VAE and benign / adversarial skill priors from demonstrations."""

from __future__ import annotations

import argparse

from seal.cli.args import add_fit_job_options, positive_int, set_torch_threads
from seal.cli.tree import CommandTree
from seal.experiments.presets import SKILLS_PRESETS


def cmd_fit_skills(args: argparse.Namespace) -> int:
    import json

    from seal.experiments.fitting.skills import fit_skills, format_summary, resolve_config

    config = resolve_config(preset=args.preset, config_file=args.config, sets=args.set, split=args.split,
                            limit=args.limit, seed=args.seed, workers=args.workers)
    set_torch_threads(config.threads)
    metrics = fit_skills(args.dataset, args.out, config, demos_path=args.demos, progress=not args.no_progress)
    print(json.dumps(metrics, indent=2, default=str) if args.json else format_summary(metrics))
    return 0


def register(tree: CommandTree) -> None:
    p = tree.group("fit").add_parser(
        "skills",
        help="train SEAL's skill VAE and benign / adversarial skill priors from demonstrations",
        description="Record (own observation, action) of every vehicle of the split's scenarios driven by the "
        "logged traffic's own actions (clean: the benign windows) and by noisy heuristic drivers, and optionally of "
        "a CAT adversary in closed loop against egos (config key ego_rollouts; resumable, in parallel). Find the "
        "collisions and near misses (box gap < 0.5 m while closing) and who struck them (the vehicle whose own "
        "motion closes the gap). Cut 10-step windows: adversarial = starting within 2H = 20 steps before an event "
        "the agent struck; benign = other windows of the logged drivers; dropped: near an out-of-road end. Train "
        "the skill VAE (LSTM encoder, closed-loop MLP decoder that sees the previous action, latent 8) and two "
        "state-conditioned RealNVP priors, each on its own windows. Writes vae.pt, prior_benign.pt, "
        "prior_adversarial.pt, metrics.json (held-out reconstruction error, prior NLL of both priors on both "
        "classes and their separation), embedding.png, config.yaml, demos_<source>.npz and CSV training logs to "
        "--out. Preset ego (the ReSkill ego's skills): a decoder that ignores the previous action and benign "
        "windows from the expert source instead (DART: the clean heuristic driver with noise on its applied "
        "action, its clean action recorded).",
    )
    add_fit_job_options(p, "skills", "seal.experiments.fitting.skills.SkillsFitConfig", "vae_train.max_epochs=5",
                        "metrics", presets=SKILLS_PRESETS)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--split", default=None, help="split to learn from (default train)")
    p.add_argument("--limit", type=positive_int("--limit"), default=None, help="use only the first N scenarios")
    p.add_argument("--demos", default=None,
                   help="folder of the demonstrations files to reuse or build (default OUT); a file there that was "
                        "built with other settings is left as it is and this fit builds its own in OUT")
    p.add_argument("--workers", type=positive_int("--workers"), default=None,
                   help="processes for the demonstrations (default 2)")
    p.set_defaults(func=cmd_fit_skills)
