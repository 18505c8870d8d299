"""Losses of the behaviour embedding: reconstruction (thesis 7.3.1) and ProtoNCE (eqs. 7.2-7.4).

* ``L_recon`` (MTR's): winner-takes-all regression of the best mode (smallest masked average displacement to the
  input trajectory; smooth L1 on its positions) plus cross-entropy of the mode logits towards that mode.
* ``L_inst`` (eq. 7.2): for sample i, the mean over its in-batch positives i+ (same label, i+ != i) of
  ``-log exp(v_i . v_i+ / tau) / sum_j exp(v_i . v_j / tau)``, the denominator over the whole batch as the equation
  writes it (j = i included). Samples without a positive in the batch add nothing.
* ``L_proto`` (eq. 7.3): ``-log exp(v_i . c_yi / phi_yi) / sum_j exp(v_i . c_j / phi_j)`` over the classes that
  have a prototype.
* Prototypes (eq. 7.4), once per epoch over all current embeddings: centroid ``c_j`` = mean embedding of class j,
  momentum-smoothed ``c_j <- eta c_j(old) + (1 - eta) c_j(new)``; concentration
  ``phi_j = sum_i ||v_i - c_j|| / (N_j log(N_j + alpha))``.

Both contrastive terms are averaged over the batch (the equations sum; the mean keeps ``lambda`` independent of the
batch size, as PCL's implementation does).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

N_CLASSES = 3


def recon_loss(traj: torch.Tensor, logits: torch.Tensor, target: torch.Tensor, valid: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(regression, mode selection)`` losses of predictions ``traj [B, M, S, 2]``, ``logits [B, M]`` against
    ``target [B, S, 2]`` (same units) with ``valid [B, S]``."""
    w = valid.float()
    n = w.sum(-1).clamp(min=1.0)
    ade = (torch.linalg.norm(traj - target[:, None], dim=-1) * w[:, None]).sum(-1) / n[:, None]  # [B, M]
    best = ade.argmin(dim=1)
    chosen = traj[torch.arange(traj.shape[0]), best]  # [B, S, 2]
    reg = (F.smooth_l1_loss(chosen, target, reduction="none").sum(-1) * w).sum(-1) / n
    return reg.mean(), F.cross_entropy(logits, best)


def instance_loss(v: torch.Tensor, labels: torch.Tensor, tau: float) -> torch.Tensor:
    """``L_inst`` of eq. 7.2 (batch mean) for unit embeddings ``v [B, D]`` and ``labels [B]``."""
    sim = v @ v.T / tau
    log_prob = sim - torch.logsumexp(sim, dim=1, keepdim=True)
    eye = torch.eye(v.shape[0], dtype=torch.bool, device=v.device)
    pos = (labels[:, None] == labels[None]) & ~eye
    n_pos = pos.sum(1)
    has = n_pos > 0
    if not bool(has.any()):
        return v.sum() * 0.0
    per_sample = -(log_prob * pos).sum(1)[has] / n_pos[has]
    return per_sample.mean()


@dataclass
class Prototypes:
    """Class prototypes of the embedding.

    Attributes:
        centroids: ``[3, D]`` c_j.
        phi: ``[3]`` concentrations phi_j.
        present: ``[3]`` bool, whether class j has had members (classes without any are left out of eq. 7.3).
    """

    centroids: torch.Tensor
    phi: torch.Tensor
    present: torch.Tensor


def prototype_loss(v: torch.Tensor, labels: torch.Tensor, protos: Prototypes) -> torch.Tensor:
    """``L_proto`` of eq. 7.3 (batch mean over samples whose class has a prototype)."""
    logits = (v @ protos.centroids.T) / protos.phi[None]
    logits = logits.masked_fill(~protos.present[None], float("-inf"))
    keep = protos.present[labels]
    if not bool(keep.any()):
        return v.sum() * 0.0
    return F.cross_entropy(logits[keep], labels[keep])


def proto_nce(v: torch.Tensor, labels: torch.Tensor, protos: Prototypes, tau: float
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(L_ProtoNCE, L_inst, L_proto)``."""
    inst = instance_loss(v, labels, tau)
    proto = prototype_loss(v, labels, protos)
    return inst + proto, inst, proto


@torch.no_grad()
def update_prototypes(v: torch.Tensor, labels: torch.Tensor, eta: float, alpha: float,
                      previous: Prototypes | None = None) -> Prototypes:
    """Prototypes from all current embeddings ``v [N, D]`` with ``labels [N]`` (eq. 7.4 and the momentum update)."""
    d = v.shape[1]
    centroids = torch.zeros(N_CLASSES, d) if previous is None else previous.centroids.clone()
    phi = torch.ones(N_CLASSES) if previous is None else previous.phi.clone()
    present = torch.zeros(N_CLASSES, dtype=torch.bool) if previous is None else previous.present.clone()
    for j in range(N_CLASSES):
        members = v[labels == j]
        n = members.shape[0]
        if n == 0:
            continue
        fresh = members.mean(0)
        centroids[j] = eta * centroids[j] + (1.0 - eta) * fresh if bool(present[j]) else fresh
        spread = torch.linalg.norm(members - centroids[j], dim=1).sum()
        phi[j] = (spread / (n * torch.log(torch.tensor(n + alpha, dtype=v.dtype)))).clamp(min=1e-6)
        present[j] = True
    return Prototypes(centroids, phi, present)
