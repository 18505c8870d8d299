"""`fit_loop` with a state file: an interrupted fit goes on after its last finished epoch and ends with the weights,
history and stop reason of an uninterrupted fit; a state of other settings, or of a fit that had stopped, is
handled as such."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from seal.models.skills.train import SkillTrainConfig, fit_loop


class _Interrupt(Exception):
    pass


def _problem(seed: int = 0) -> tuple[torch.nn.Module, torch.Tensor, torch.Tensor]:
    torch.manual_seed(seed)
    x = torch.randn(300, 4)
    y = x @ torch.tensor([[1.0], [-2.0], [0.5], [0.0]]) + 0.1 * torch.randn(300, 1)
    return torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.ReLU(), torch.nn.Linear(8, 1)), x, y


def _fit(cfg: SkillTrainConfig, state: Path | None, key: str = "k", fail_at_validation: int | None = None
         ) -> tuple[torch.nn.Module, object]:
    model, x, y = _problem()
    calls = []

    def batch_loss(idx: np.ndarray):
        i = torch.from_numpy(idx)
        noise = 0.01 * torch.randn(len(idx), 1)  # draws on torch's generator, as the VAE's reparameterisation does
        return ((model(x[i]) + noise - y[i]) ** 2).mean(), {}

    def validate():
        calls.append(1)
        if fail_at_validation is not None and len(calls) == fail_at_validation:
            raise _Interrupt
        return {"loss": float(((model(x[:50]) - y[:50]) ** 2).mean())}

    return model, fit_loop(model, 300, batch_loss, validate, cfg, desc="t", progress=False, state_path=state,
                           state_key=key)


def _same(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    return all(torch.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values(), strict=True))


def test_an_interrupted_fit_goes_on_to_the_uninterrupted_result(tmp_path: Path) -> None:
    cfg = SkillTrainConfig(batch_size=32, max_epochs=6, patience=10, seed=3, epoch_windows=200)
    whole, whole_fit = _fit(cfg, None)
    state = tmp_path / "m.pt.state"
    with pytest.raises(_Interrupt):  # validation 1 is epoch 0's; the 4th is epoch 3's: epochs 1-2 are kept
        _fit(cfg, state, fail_at_validation=4)
    assert state.is_file()
    resumed, fit = _fit(cfg, state)
    assert _same(whole, resumed)
    rows = [{k: v for k, v in r.items() if k != "seconds"} for r in fit.history]
    assert rows == [{k: v for k, v in r.items() if k != "seconds"} for r in whole_fit.history]
    assert (fit.best_epoch, fit.best_val, fit.stop_reason) == (whole_fit.best_epoch, whole_fit.best_val,
                                                              whole_fit.stop_reason)


def test_a_state_of_other_settings_is_not_used(tmp_path: Path) -> None:
    cfg = SkillTrainConfig(batch_size=32, max_epochs=3, patience=10, seed=3)
    state = tmp_path / "m.pt.state"
    _fit(cfg, state, key="other data")
    whole, _ = _fit(cfg, None)
    again, fit = _fit(cfg, state, key="this data")
    assert _same(whole, again) and len(fit.history) == 4
    state.write_bytes(b"not a state")  # damaged: trained from the start, not an error
    damaged, _ = _fit(cfg, state, key="this data")
    assert _same(whole, damaged)


def test_a_fit_that_had_stopped_trains_no_further(tmp_path: Path) -> None:
    cfg = SkillTrainConfig(batch_size=32, max_epochs=40, patience=1, lr=0.5, seed=3)  # too large a step: stops early
    state = tmp_path / "m.pt.state"
    first, fit = _fit(cfg, state)
    assert fit.stop_reason.startswith("early stop") and len(fit.history) < 41
    again, fit2 = _fit(cfg, state)
    assert _same(first, again) and fit2.stop_reason == fit.stop_reason and len(fit2.history) == len(fit.history)
