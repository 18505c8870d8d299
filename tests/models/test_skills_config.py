"""``seal fit skills`` configuration: presets, overrides and errors that name the option."""

from __future__ import annotations

import pytest

from seal.experiments.fitting.skills import SkillsFitConfig, resolve_config


def test_presets_and_overrides_merge_nested_sections(tmp_path) -> None:
    quick = resolve_config("quick")
    assert quick.limit == 120 and quick.vae_train["max_epochs"] == 8
    assert quick.vae_train["batch_size"] == SkillsFitConfig().vae_train["batch_size"]  # nested keys merge
    path = tmp_path / "c.yaml"
    path.write_text("demos: {impaired_share: 0.2}\nvae_train: {lr: 0.002}\n")
    cfg = resolve_config("standard", path, limit=7, seed=None)
    assert cfg.demos == {"impaired_share": 0.2} and cfg.vae_train["lr"] == 0.002
    assert cfg.vae_train["max_epochs"] == 20 and cfg.limit == 7 and cfg.seed == 0
    cfg = resolve_config("standard", path, sets=["vae_train.max_epochs=3"])
    assert cfg.vae_train["max_epochs"] == 3 and cfg.vae_train["lr"] == 0.002


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("bogus: 1\n", "bogus"),
        ("demos: {noise: 1}\n", r"bad\.yaml.*demos\.noise"),
        ("vae: {latent: 3}\n", r"bad\.yaml.*vae\.latent"),
        ("prior_train: {epochs: 3}\n", r"bad\.yaml.*prior_train\.epochs"),
        ("windows: {horizon: 0}\n", "horizon"),
        ("val_fraction: 1.5\n", "val_fraction"),
    ],
)
def test_bad_options_are_named(tmp_path, text: str, match: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        resolve_config("quick", path)
