"""The generator registry: one table of built-in generators, their options (model files marked) and which are
training pipelines; the CLI's choices and the training config come from it."""

from __future__ import annotations

import inspect

from seal.adversaries.base import (
    GENERATORS,
    NO_ADVERSARY,
    available_generators,
    generator_class,
    model_file_options,
    pipeline_names,
)


def test_pipelines_come_from_the_registry() -> None:
    assert pipeline_names() == (NO_ADVERSARY, "goose", "cat", "seal", "steered", "cat-rcg", "seal-rcg")
    from seal.experiments.training.config import PIPELINES, EgoTrainConfig

    assert pipeline_names() == PIPELINES
    pipelines = EgoTrainConfig().pipelines
    assert tuple(pipelines) == PIPELINES and pipelines[NO_ADVERSARY] is None
    for name in PIPELINES[1:]:  # each pipeline's model files start unset
        spec = pipelines[name]
        assert spec is not None and spec.name == name and spec.kwargs == dict.fromkeys(GENERATORS[name].model_files())


def test_declared_options_are_constructor_arguments() -> None:
    for name, spec in GENERATORS.items():
        cls = generator_class(name)
        assert cls.name == name
        params = inspect.signature(cls).parameters
        assert {o.name for o in spec.options} <= set(params), name
    assert model_file_options("seal") == {"prior": (), "objective": ("cat",), "skills": ()}
    assert model_file_options("steered") == {"prior": (), "steer": ()}
    assert model_file_options("goose") == {"model": ()} and model_file_options("replay") == {}


def test_cli_choices_are_the_registry() -> None:
    from seal.cli import build_parser
    from seal.cli.args import generator_choices, pipeline_choices
    from seal.cli.train import ALGOS
    from seal.experiments.training.config import ALGOS as CONFIG_ALGOS

    assert tuple(pipeline_choices()) == pipeline_names() and "cat" in pipeline_choices()
    # the built-in generators, plus any registered at run time (plugins, test generators of other modules)
    assert set(generator_choices()) == set(available_generators()) and set(GENERATORS) <= set(generator_choices())
    assert ALGOS == CONFIG_ALGOS
    args = build_parser().parse_args(["train", "--out", "o", "--pipeline", "noadv", "--set", "seed=3"])
    assert args.pipeline == "noadv" and args.set == ["seed=3"]
