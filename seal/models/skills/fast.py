"""Compiled inference for one observation at a time (the skill policy's per-step path).

For a single observation torch's per-operation overhead (~5-10 us) dominates: decoding one action costs ~100 us and
sampling a skill ~800 us in torch; as numpy a decode still took ~10 calls of ~1 us overhead each. Here a decode
and a skill draw are one compiled (numba) call each. The weights are copied from the torch modules (float32, the
same operations in float32, summed in another order), so results agree with `SkillVAE.decode` /
`ConditionalRealNVP.sample` to float32 rounding; a change of the torch weights needs a new snapshot.

Each linear layer is stored transposed (``[in, out]``, row ``j`` = input ``j``'s weights to every output) and
computed as a sum of input-scaled rows: the inner loop runs over independent outputs (vectorised) and skips
inputs that are 0 (after a ReLU about half of them), which changes nothing but the work. The kernels have explicit
signatures, so numba compiles them (or loads them from its cache) when this module is imported.
"""

from __future__ import annotations

import math

import numpy as np
from numba import float32, int64, njit
from torch import nn

from seal.models.skills.realnvp import ConditionalRealNVP
from seal.models.skills.vae import SkillVAE

Layers = list[tuple[np.ndarray, np.ndarray]]
_F4 = float32[::1]
_I8 = int64[::1]
_I8_2D = int64[:, ::1]
# Kernels take fastmath={"contract"} (FMA contraction) only: the outputs are independent, so no reassociation is
# needed to vectorise.


def _layers(seq: nn.Sequential) -> Layers:
    """(weight ``[out, in]``, bias ``[out]``) of every Linear of a ReLU MLP built by `seal.models.skills.vae.mlp`."""
    return [
        (m.weight.detach().cpu().numpy().astype(np.float32).copy(), m.bias.detach().cpu().numpy().astype(np.float32))
        for m in seq if isinstance(m, nn.Linear)
    ]


def _pack(layers: Layers) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An MLP's layers as (transposed weights, flat ``[sum in * out]`` float32; biases, flat; sizes ``[in, out_1,
    ..., out_L]`` int64)."""
    w = np.concatenate([np.ascontiguousarray(wt.T).ravel() for wt, _ in layers]).astype(np.float32)
    b = np.concatenate([bias for _, bias in layers]).astype(np.float32)
    dims = np.array([layers[0][0].shape[1], *(wt.shape[0] for wt, _ in layers)], dtype=np.int64)
    return w, b, dims


@njit(cache=True, nogil=True, fastmath={"contract"})
def _dense(x: np.ndarray, w: np.ndarray, w_off: int, b: np.ndarray, b_off: int, n_out: int, relu: bool
           ) -> np.ndarray:
    """``y = W x + b`` (then ReLU if ``relu``) for ``x [n_in]``, ``W`` transposed at ``w[w_off:]``, ``b`` at
    ``b[b_off:]``."""
    y = b[b_off : b_off + n_out].copy()
    # One slice at the layer's offset, then plain row offsets: with the offset added inside the loop (or a slice
    # per row) LLVM does not vectorise the inner loop (5-7x slower).
    wl = w[w_off:]
    for j in range(x.shape[0]):
        xj = x[j]
        if xj != 0.0:
            base = j * n_out
            for i in range(n_out):
                y[i] += xj * wl[base + i]
    if relu:
        for i in range(n_out):
            if y[i] < 0.0:
                y[i] = 0.0
    return y


@njit(cache=True, nogil=True, fastmath={"contract"})
def _mlp(x: np.ndarray, w: np.ndarray, w_off: int, b: np.ndarray, b_off: int, dims: np.ndarray) -> np.ndarray:
    """ReLU MLP forward (no output activation) of a `_pack`-ed MLP starting at ``w[w_off:]`` / ``b[b_off:]``."""
    h = x
    n_layers = dims.shape[0] - 1
    for k in range(n_layers):
        n_out = dims[k + 1]
        h = _dense(h, w, w_off, b, b_off, n_out, k < n_layers - 1)
        w_off += dims[k] * n_out
        b_off += n_out
    return h


@njit(_F4(_F4, _F4, _F4, _F4, _F4, _I8), cache=True, nogil=True, fastmath={"contract"})
def decode_action(obs: np.ndarray, w_obs: np.ndarray, bias: np.ndarray, w: np.ndarray, b: np.ndarray,
                  dims: np.ndarray) -> np.ndarray:
    """Action ``tanh(MLP(obs))``: first layer ``w_obs`` (transposed, flat) with the skill's ``bias``, then the
    `_pack`-ed rest (``w``, ``b``, ``dims``)."""
    h = _dense(obs, w_obs, 0, bias, 0, bias.shape[0], True)
    out = _mlp(h, w, 0, b, 0, dims)
    for i in range(out.shape[0]):
        out[i] = math.tanh(out[i])
    return out


@njit(_F4(_F4, _F4, _F4, _F4, _F4, _F4, _I8, _I8_2D, _I8_2D, _F4, _F4, _I8_2D, _I8, _I8, _F4, _F4, _F4), cache=True,
      nogil=True, fastmath={"contract"})
def sample_latent(
    noise: np.ndarray, cond: np.ndarray, cond_mean: np.ndarray, cond_std: np.ndarray, e_w: np.ndarray,
    e_b: np.ndarray, e_dims: np.ndarray, keep: np.ndarray, change: np.ndarray, c_w: np.ndarray, c_b: np.ndarray,
    c_dims: np.ndarray, c_woff: np.ndarray, c_boff: np.ndarray, clamps: np.ndarray, z_mean: np.ndarray,
    z_std: np.ndarray,
) -> np.ndarray:
    """``ConditionalRealNVP.sample`` of one noise ``[L]`` for one state ``[D]``: the state embedding (ReLU MLP, then
    ReLU), then the couplings inverted in reverse order, then the latent de-standardisation.

    Coupling ``k`` (of ``K``): dims ``keep[k]`` pass through and condition dims ``change[k]`` (``[K, <= L]``,
    padded with -1 where the halves differ in size); its net
    (sizes ``c_dims[k]``, weights at ``c_woff[k]`` / ``c_boff[k]`` of ``c_w`` / ``c_b``) maps ``[x_keep, e]`` to
    ``(raw, shift)``; ``a = clamp tanh(raw / clamp)``; ``x_change <- (x_change - shift) exp(-a)``.
    """
    e = _mlp((cond - cond_mean) / cond_std, e_w, 0, e_b, 0, e_dims)
    for i in range(e.shape[0]):
        if e[i] < 0.0:
            e[i] = 0.0
    x = noise.copy()
    for k in range(keep.shape[0] - 1, -1, -1):
        n_keep = np.count_nonzero(keep[k] >= 0)
        n_change = np.count_nonzero(change[k] >= 0)
        inp = np.empty(n_keep + e.shape[0], dtype=np.float32)
        inp[n_keep:] = e
        for i in range(n_keep):
            inp[i] = x[keep[k, i]]
        out = _mlp(inp, c_w, c_woff[k], c_b, c_boff[k], c_dims[k])
        clamp = clamps[k]
        for i in range(n_change):
            a = clamp * math.tanh(out[i] / clamp)
            x[change[k, i]] = (x[change[k, i]] - out[n_change + i]) * math.exp(-a)
    return x * z_std + z_mean


def _padded(rows: list[np.ndarray]) -> np.ndarray:
    """Index rows of different lengths as one ``[K, max length]`` int64 array padded with -1."""
    out = np.full((len(rows), max(r.size for r in rows)), -1, dtype=np.int64)
    for k, r in enumerate(rows):
        out[k, : r.size] = r
    return out


class FastDecoder:
    """`SkillVAE.decode` for one observation: the input standardisation and the ignored slots are folded into the
    first layer, and the latent's contribution to it is computed once per skill (`set_skill`)."""

    def __init__(self, vae: SkillVAE) -> None:
        layers = _layers(vae.decoder)
        d = vae.config.obs_dim
        w1, b1 = layers[0]
        mean = vae.obs_mean.cpu().numpy().astype(np.float32)
        std = vae.obs_std.cpu().numpy().astype(np.float32)
        keep = vae.decoder_keep.cpu().numpy().astype(np.float32)
        w_obs = (w1[:, :d] * keep / std).astype(np.float32)
        self._w_obs = np.ascontiguousarray(w_obs.T).ravel()
        self._b_obs = (b1 - w_obs @ mean).astype(np.float32)
        self._w_z = w1[:, d:].copy()
        self._w, self._b, self._dims = _pack(layers[1:])
        self._bias = self._b_obs.copy()

    def set_skill(self, z: np.ndarray) -> None:
        """Latent ``[latent_dim]`` used by the following `decode` calls."""
        self._bias = (self._b_obs + self._w_z @ np.asarray(z, dtype=np.float32)).astype(np.float32)

    def decode(self, obs: np.ndarray) -> np.ndarray:
        """Action ``[action_dim]`` float32 in [-1, 1] for one observation ``[obs_dim]`` (float32, contiguous)."""
        return decode_action(obs, self._w_obs, self._bias, self._w, self._b, self._dims)


class FastPriorSampler:
    """`ConditionalRealNVP.sample` for one state."""

    def __init__(self, prior: ConditionalRealNVP) -> None:
        def f4(t: object) -> np.ndarray:
            return np.ascontiguousarray(np.asarray(t, dtype=np.float32))

        self._cond = (f4(prior.cond_mean.cpu().numpy()), f4(prior.cond_std.cpu().numpy()))
        self._embed = _pack(_layers(prior.embed_mlp))
        couplings = prior.coupling_layers
        packed = [_pack(_layers(c.net)) for c in couplings]
        self._keep = _padded([c.keep.cpu().numpy() for c in couplings])
        self._change = _padded([c.change.cpu().numpy() for c in couplings])
        self._c_w = np.concatenate([p[0] for p in packed])
        self._c_b = np.concatenate([p[1] for p in packed])
        self._c_dims = np.stack([p[2] for p in packed])
        self._c_woff = np.cumsum([0] + [p[0].size for p in packed[:-1]]).astype(np.int64)
        self._c_boff = np.cumsum([0] + [p[1].size for p in packed[:-1]]).astype(np.int64)
        self._clamps = np.array([c.clamp for c in couplings], dtype=np.float32)
        self._z = (f4(prior.z_mean.cpu().numpy()), f4(prior.z_std.cpu().numpy()))

    def sample(self, noise: np.ndarray, cond: np.ndarray) -> np.ndarray:
        """Latent ``[latent_dim]`` float32 for noise ``[latent_dim]`` and state ``[cond_dim]``."""
        return sample_latent(
            np.ascontiguousarray(noise, dtype=np.float32), np.ascontiguousarray(cond, dtype=np.float32),
            *self._cond, *self._embed, self._keep, self._change, self._c_w, self._c_b, self._c_dims, self._c_woff,
            self._c_boff, self._clamps, *self._z,
        )
