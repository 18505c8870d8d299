"""Behaviour embedding losses and adapter: ProtoNCE on a toy batch against a hand computation (eqs. 7.2-7.4), the
reconstruction loss's mode choice, LoRA starting as the identity (B = 0) and fine-tuning moving only A and B."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from seal.models.behavior.features import BehaviorFeatureConfig
from seal.models.behavior.losses import (
    Prototypes,
    instance_loss,
    proto_nce,
    prototype_loss,
    recon_loss,
    update_prototypes,
)
from seal.models.behavior.network import BehaviorConfig, BehaviorNet
from seal.models.behavior.train import BehaviorTrainConfig, Tensors, finetune

TAU = 0.5


def _unit(deg: float) -> list[float]:
    return [math.cos(math.radians(deg)), math.sin(math.radians(deg))]


def toy_batch() -> tuple[torch.Tensor, torch.Tensor]:
    """Four unit vectors at 0, 60, 180, 270 degrees; labels safe, safe, neutral, unsafe."""
    v = torch.tensor([_unit(0), _unit(60), _unit(180), _unit(270)], dtype=torch.float64)
    return v, torch.tensor([0, 0, 1, 2])


def test_instance_loss_matches_a_hand_computation() -> None:
    v, y = toy_batch()
    # Dot products: row 0 -> [1, 0.5, -1, 0]; row 1 -> [0.5, 1, -0.5, -sqrt(3)/2]. Only rows 0 and 1 have a
    # positive (each other); the denominator runs over the whole batch, self included (eq. 7.2 as written).
    d0 = math.exp(1 / TAU) + math.exp(0.5 / TAU) + math.exp(-1 / TAU) + math.exp(0 / TAU)
    d1 = math.exp(0.5 / TAU) + math.exp(1 / TAU) + math.exp(-0.5 / TAU) + math.exp(-math.sqrt(3) / 2 / TAU)
    l0 = -math.log(math.exp(0.5 / TAU) / d0)
    l1 = -math.log(math.exp(0.5 / TAU) / d1)
    assert instance_loss(v, y, TAU).item() == pytest.approx((l0 + l1) / 2, rel=1e-9)


def test_prototype_loss_and_protonce_match_a_hand_computation() -> None:
    v, y = toy_batch()
    c = torch.tensor([_unit(30), _unit(180), _unit(270)], dtype=torch.float64)
    phi = torch.tensor([0.2, 0.5, 0.25], dtype=torch.float64)
    protos = Prototypes(c, phi, torch.tensor([True, True, True]))
    expected = []
    for i in range(4):
        dots = [float(v[i] @ c[j]) / float(phi[j]) for j in range(3)]
        expected.append(-math.log(math.exp(dots[int(y[i])]) / sum(math.exp(d) for d in dots)))
    assert prototype_loss(v, y, protos).item() == pytest.approx(np.mean(expected), rel=1e-9)
    total, inst, proto = proto_nce(v, y, protos, TAU)
    assert total.item() == pytest.approx(inst.item() + proto.item())
    # A class without a prototype drops out of the denominator and its samples out of the mean.
    partial = Prototypes(c, phi, torch.tensor([True, True, False]))
    kept = []
    for i in range(3):
        dots = [float(v[i] @ c[j]) / float(phi[j]) for j in range(2)]
        kept.append(-math.log(math.exp(dots[int(y[i])]) / sum(math.exp(d) for d in dots)))
    assert prototype_loss(v, y, partial).item() == pytest.approx(np.mean(kept), rel=1e-9)


def test_prototype_update_is_the_momentum_mean_and_eq_7_4_concentration() -> None:
    v = torch.tensor([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]], dtype=torch.float64)
    y = torch.tensor([0, 0, 2])
    first = update_prototypes(v, y, eta=0.8, alpha=10.0)
    np.testing.assert_allclose(first.centroids[0].numpy(), [0.5, 0.5])
    np.testing.assert_allclose(first.centroids[2].numpy(), [-1.0, 0.0])
    assert first.present.tolist() == [True, False, True]
    # phi_0 = (|v0 - c| + |v1 - c|) / (2 log(2 + 10)), |v - c| = sqrt(0.5)
    assert first.phi[0].item() == pytest.approx(2 * math.sqrt(0.5) / (2 * math.log(12)))
    moved = update_prototypes(torch.tensor([[1.0, 0.0], [1.0, 0.0]], dtype=torch.float64), torch.tensor([0, 0]),
                              eta=0.8, alpha=10.0, previous=first)
    np.testing.assert_allclose(moved.centroids[0].numpy(), [0.8 * 0.5 + 0.2 * 1.0, 0.8 * 0.5])
    np.testing.assert_allclose(moved.centroids[2].numpy(), [-1.0, 0.0])  # no members: kept


def test_recon_loss_trains_the_mode_closest_to_the_target() -> None:
    target = torch.zeros(1, 3, 2)
    traj = torch.stack([torch.full((3, 2), 2.0), torch.full((3, 2), 0.1)])[None]  # mode 1 is closer
    logits = torch.tensor([[0.0, 0.0]])
    reg, cls = recon_loss(traj, logits, target, torch.ones(1, 3, dtype=torch.bool))
    assert reg.item() == pytest.approx(2 * 0.5 * 0.1**2)  # smooth L1 (beta 1) summed over x, y, mean over rows
    assert cls.item() == pytest.approx(math.log(2))
    # Invalid rows count for neither the mode choice nor the loss.
    traj[0, 0, 0] = 0.0
    traj[0, 1, 0] = 50.0
    valid = torch.tensor([[True, False, False]])
    reg, _ = recon_loss(traj, logits, target, valid)
    assert reg.item() == pytest.approx(0.0)


def small_net(seed: int = 0) -> BehaviorNet:
    torch.manual_seed(seed)
    return BehaviorNet(BehaviorConfig(features=BehaviorFeatureConfig(n_agents=3, stride_steps=10), d_model=16,
                                      n_heads=2, n_layers=1, latent_dim=24, proj_dim=4, lora_rank=4, n_modes=2))


def _random_tensors(net: BehaviorNet, n: int, seed: int) -> Tensors:
    g = torch.Generator().manual_seed(seed)
    f = net.cfg.features
    agents = torch.randn(n, f.n_agents, f.token_features, generator=g)
    return Tensors(agents, torch.ones(n, f.n_agents, dtype=torch.bool), torch.randn(n, f.n_rows, 2, generator=g),
                   torch.ones(n, f.n_rows, dtype=torch.bool), torch.arange(n) % 3)


def test_lora_starts_as_the_identity() -> None:
    net = small_net()
    assert torch.count_nonzero(net.lora_b.weight) == 0
    z = torch.randn(5, 24)
    torch.testing.assert_close(net.project(z, lora=True), net.project(z, lora=False), rtol=0, atol=0)
    norms = torch.linalg.norm(net.project(z), dim=1)
    torch.testing.assert_close(norms, torch.ones(5))


def test_finetuning_moves_only_the_adapter_and_changes_the_embedding() -> None:
    net = small_net()
    data = _random_tensors(net, 24, seed=1)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    protos = update_prototypes(net.project(net.encode(data.agents, data.mask)).detach(), data.labels, 0.8, 10.0)
    cfg = BehaviorTrainConfig(finetune_epochs=3, finetune_batch_size=8, finetune_lr=0.05)
    finetune(net, data, cfg, protos)
    after = net.state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed == {"lora_a.weight", "lora_b.weight"}
    assert torch.count_nonzero(net.lora_b.weight) > 0
    z = net.encode(data.agents, data.mask)
    assert not torch.allclose(net.project(z, lora=True), net.project(z, lora=False))
    assert all(p.requires_grad for p in net.parameters())  # frozen only while fine-tuning


def test_a_stage_runs_every_epoch_without_a_cap_and_stops_after_one_when_the_cap_is_spent() -> None:
    # `max_minutes: null` (the decisive preset): the epochs alone decide, so the embedding does not depend on the
    # machine's speed; a cap that is spent at once ends the stage after its first epoch.
    logs = {}
    for cap in (None, 1e-9):
        net = small_net()
        data = _random_tensors(net, 16, seed=1)
        protos = update_prototypes(net.project(net.encode(data.agents, data.mask)).detach(), data.labels, 0.8, 10.0)
        cfg = BehaviorTrainConfig(finetune_epochs=3, finetune_batch_size=8, max_minutes=cap)
        logs[cap] = finetune(net, data, cfg, protos)[1]
    assert len(logs[None]) == 3 and len(logs[1e-9]) == 1
    with pytest.raises(ValueError, match="max_minutes"):
        BehaviorTrainConfig(max_minutes=0.0)
