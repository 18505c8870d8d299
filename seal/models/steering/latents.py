"""The prior's hidden states at each encoder site, and decoding with a steered target state.

Sites (paper 002 measures several modules; paper 000 one latent):

* ``input``: the agent's token embedding before the transformer;
* ``layer1`` .. ``layer{n-1}``: the token after each transformer layer but the last;
* ``output``: after the last layer and the encoder's LayerNorm: the latent the decoder reads
  (`seal.models.prior.Encoding.target_latent`).

Steering at a site adds an offset ``[d_model]`` to the target's token (index 0) at that site and runs the rest of
the encoder and the decoder unchanged; only the target's own token moves, so other agents' tokens see the change
only through attention in the later layers.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from seal.core.scenario import Scenario
from seal.models.prior.features import featurise
from seal.models.prior.prior import TrajectoryPrior, to_world

OUTPUT = "output"
INPUT = "input"


def site_names(prior: TrajectoryPrior) -> tuple[str, ...]:
    """The steering sites of ``prior`` in encoder order (`INPUT`, ``layer1`` .., `OUTPUT`)."""
    return (INPUT, *(f"layer{i}" for i in range(1, prior.config.n_layers)), OUTPUT)


def _site_index(prior: TrajectoryPrior, site: str) -> int:
    names = site_names(prior)
    if site not in names:
        raise ValueError(f"unknown latent site {site!r}; this prior has {', '.join(names)}")
    return names.index(site)


@dataclass(frozen=True)
class SceneBatch:
    """Featurised targets, one per scene (`prepare`).

    Attributes:
        feats: the prior's input features (`seal.models.prior.features.featurise`), batch ``B``.
        pose: ``[B, 3]`` each target's frame in the world (x, y in m, heading in rad).
    """

    feats: dict[str, torch.Tensor]
    pose: np.ndarray

    @property
    def size(self) -> int:
        return int(self.pose.shape[0])


def prepare(prior: TrajectoryPrior, scenarios: Sequence[Scenario], agents: Sequence[int]) -> SceneBatch:
    """Features of target ``agents[k]`` in ``scenarios[k]`` (each needs 2 valid history steps, as the prior)."""
    for s, a in zip(scenarios, agents, strict=True):
        prior._check_history(s, int(a))
    tables = prior.tables(scenarios, [int(a) for a in agents])
    return SceneBatch(featurise(tables, slice(None), prior.config.features), tables.pose)


@torch.no_grad()
def tokens_at(prior: TrajectoryPrior, batch: SceneBatch, site: str) -> tuple[torch.Tensor, torch.Tensor]:
    """All tokens ``[B, N, d_model]`` at ``site`` and the token mask ``[B, N]`` (True = present)."""
    net, feats = prior.net, batch.feats
    stop = _site_index(prior, site)
    agents = net.agent_in(feats["agents"]) + net.kind[0]
    chunks = net.chunk_in(feats["chunks"]) + net.kind[1]
    x = torch.cat([agents, chunks], dim=1)
    mask = torch.cat([feats["agent_mask"], feats["chunk_mask"]], dim=1)
    for layer in list(net.encoder.layers)[:stop]:
        x = layer(x, src_key_padding_mask=~mask)
    if stop == len(net.encoder.layers):
        x = net.encoder_norm(x)
    return x, mask


@torch.no_grad()
def finish(prior: TrajectoryPrior, site: str, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Continue the encoder from ``tokens`` at ``site`` to the output tokens ``[B, N, d_model]``."""
    net = prior.net
    start = _site_index(prior, site)
    layers = list(net.encoder.layers)
    if start == len(layers):
        return tokens
    x = tokens
    for layer in layers[start:]:
        x = layer(x, src_key_padding_mask=~mask)
    return net.encoder_norm(x)


def hidden_states(prior: TrajectoryPrior, batch: SceneBatch) -> dict[str, np.ndarray]:
    """The target's state ``[B, d_model]`` at every site (float64)."""
    return {site: tokens_at(prior, batch, site)[0][:, 0].double().numpy() for site in site_names(prior)}


@torch.no_grad()
def decode_tokens(prior: TrajectoryPrior, batch: SceneBatch, tokens: torch.Tensor, mask: torch.Tensor
                  ) -> tuple[np.ndarray, np.ndarray]:
    """World-frame candidates ``[B, K, 80, 2]`` (m) and probabilities ``[B, K]`` from output tokens."""
    xy, logits = prior.net.decode(tokens, mask, batch.feats["start"])
    return to_world(xy.double().numpy(), batch.pose), torch.softmax(logits.double(), dim=1).numpy()


class SteeringSession:
    """Decode one batch many times with different target offsets at one site (the tokens up to the site are
    computed once).

    Args:
        prior: the trajectory prior.
        batch: the targets (`prepare`).
        site: where offsets are added (`site_names`).
    """

    def __init__(self, prior: TrajectoryPrior, batch: SceneBatch, site: str) -> None:
        self.prior, self.batch, self.site = prior, batch, site
        self.tokens, self.mask = tokens_at(prior, batch, site)

    @property
    def target_state(self) -> np.ndarray:
        """``[B, d_model]`` the targets' unsteered states at the site."""
        return self.tokens[:, 0].double().numpy()

    def decode(self, offset: np.ndarray | torch.Tensor | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Candidates ``[B, K, 80, 2]`` (world, m) and probabilities ``[B, K]`` with ``offset`` (``[d_model]`` or
        ``[B, d_model]``; None = unsteered) added to each target's state at the site."""
        tokens = self.tokens
        if offset is not None:
            tokens = tokens.clone()
            tokens[:, 0] = tokens[:, 0] + torch.as_tensor(np.array(offset), dtype=tokens.dtype)
        out = finish(self.prior, self.site, tokens, self.mask)
        return decode_tokens(self.prior, self.batch, out, self.mask)
