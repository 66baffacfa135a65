"""Skin model: rescores each vertex's candidate bones (UniRig §6, on a candidate set).

Inputs are the arrays of `src/rig/skin/features.rs` (the `skin-v1` contract, see
ONNX_CONTRACT.md), for R vertex rows, B bones and K candidates per row:

* ``vert``  (R, 6)      position and normal in the mesh's unit frame
* ``bone``  (B, 17)     head, tail, length, depth, flags, name hints, mesh share
* ``cand``  (R, K)      candidate bone indices, nearest first, -1 pads
* ``pair``  (R, K, 11)  geodesic distance, geometric blend, offsets, ...

Per-point features (an MLP over a Fourier encoding), per-bone features (an MLP over
head/tail with positional encoding, then self-attention over the skeleton), a pair MLP
with the Rust distance features, point-to-candidate cross-attention, an output MLP, and a
softmax over the candidates. The logit is a residual on the log of the geometric blend, so
an untrained head already gives the geometric weights and training learns corrections
(chiefly: which bones artists leave unweighted).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Optional

import torch
import torch.nn as nn
import torch.nn.functional as F

VERT_FEATURES = 6
BONE_FEATURES = 17
PAIR_FEATURES = 11
# Column of `pair` holding the geometric blend over the candidates (sums to 1 per row).
PAIR_BLEND = 2
# Columns of `bone` holding the name hints (end, control, twist).
NAME_HINTS = slice(12, 15)
NEG = -1e4


@dataclass
class SkinConfig:
    d: int = 64
    heads: int = 4
    freqs: int = 4
    bone_layers: int = 1
    # Off: the bone name hints (columns NAME_HINTS of `bone`) are zeroed, so the model
    # judges bones by geometry and topology alone (as for generically named skeletons).
    name_hints: bool = True

    def to_dict(self):
        return asdict(self)

    @staticmethod
    def from_dict(d):
        return SkinConfig(**{k: v for k, v in d.items() if k in SkinConfig.__dataclass_fields__})


def fourier(x: torch.Tensor, freqs: int) -> torch.Tensor:
    """sin/cos of x·2^i·π, i < freqs, for the last axis (unit-frame coordinates)."""
    scales = (2.0 ** torch.arange(freqs, dtype=x.dtype, device=x.device)) * math.pi
    y = x.unsqueeze(-1) * scales
    return torch.cat([torch.sin(y), torch.cos(y)], dim=-1).flatten(-2)


def mlp(i: int, h: int, o: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(i, h), nn.GELU(), nn.Linear(h, o))


class Attention(nn.Module):
    """Multi-head attention written out with matmuls (exports to plain ONNX ops)."""

    def __init__(self, d: int, heads: int):
        super().__init__()
        self.h, self.dh = heads, d // heads
        self.q, self.k, self.v, self.o = (nn.Linear(d, d) for _ in range(4))

    def forward(self, q_in, kv_in, bias: Optional[torch.Tensor] = None):
        # q_in (..., Q, d), kv_in (..., S, d), bias broadcastable to (..., h, Q, S)
        def split(x):
            return x.unflatten(-1, (self.h, self.dh)).transpose(-2, -3)

        q, k, v = split(self.q(q_in)), split(self.k(kv_in)), split(self.v(kv_in))
        s = q @ k.transpose(-1, -2) / math.sqrt(self.dh)
        if bias is not None:
            s = s + bias
        y = torch.softmax(s, dim=-1) @ v
        return self.o(y.transpose(-2, -3).flatten(-2))


class BoneLayer(nn.Module):
    def __init__(self, d: int, heads: int):
        super().__init__()
        self.n1, self.n2 = nn.LayerNorm(d), nn.LayerNorm(d)
        self.att = Attention(d, heads)
        self.ff = mlp(d, 2 * d, d)

    def forward(self, x, bias=None):
        h = self.n1(x)
        x = x + self.att(h, h, bias)
        return x + self.ff(self.n2(x))


class SkinModel(nn.Module):
    def __init__(self, cfg: SkinConfig):
        super().__init__()
        self.cfg = cfg
        d, f = cfg.d, cfg.freqs
        pe = 3 * 2 * f
        self.vert_in = mlp(pe + VERT_FEATURES, d, d)
        self.bone_in = mlp(2 * pe + BONE_FEATURES, d, d)
        self.bone_layers = nn.ModuleList(BoneLayer(d, cfg.heads) for _ in range(cfg.bone_layers))
        self.bone_out = nn.LayerNorm(d)
        self.pair_in = mlp(2 * d + PAIR_FEATURES + pe, d, d)
        self.cross = Attention(d, cfg.heads)
        self.head = mlp(2 * d, d, 1)
        self.geo_scale = nn.Parameter(torch.ones(()))
        # Start from the geometric weights: a zero correction.
        nn.init.zeros_(self.head[2].weight)
        nn.init.zeros_(self.head[2].bias)

    def logits(self, vert, bone, cand, pair, bone_item: Optional[torch.Tensor] = None):
        """Masked logits (R, K). `bone_item` (B,) keeps bones of different meshes of a
        training batch from attending to each other; inference runs one mesh."""
        f = self.cfg.freqs
        if not self.cfg.name_hints:
            keep = torch.ones(BONE_FEATURES, dtype=bone.dtype)
            keep[NAME_HINTS] = 0.0
            bone = bone * keep
        valid = cand >= 0
        idx = torch.where(valid, cand, torch.zeros_like(cand))
        ve = self.vert_in(torch.cat([fourier(vert[:, :3], f), vert], dim=-1))
        be = self.bone_in(torch.cat([fourier(bone[:, 0:3], f), fourier(bone[:, 3:6], f), bone], dim=-1))
        bias = None
        if bone_item is not None:
            bias = torch.where(bone_item[:, None] == bone_item[None, :], 0.0, NEG)
        for layer in self.bone_layers:
            be = layer(be, bias)
        be = self.bone_out(be)
        r, k = cand.shape[0], cand.shape[1]
        d = ve.shape[-1]
        # pair_in's first layer on [vertex; bone; pair features; offset] is split by
        # columns, so the vertex and bone parts run once per row and per bone rather than
        # once per pair (the same function, about half the work at inference).
        w1, b1 = self.pair_in[0].weight, self.pair_in[0].bias
        rel = vert[:, None, :3] - bone[idx][..., 0:3]
        pre = (F.linear(ve, w1[:, :d], b1)[:, None, :] + F.linear(be, w1[:, d:2 * d])[idx]
               + F.linear(torch.cat([pair, fourier(rel, f)], dim=-1), w1[:, 2 * d:]))
        h = self.pair_in[2](self.pair_in[1](pre))
        key_bias = torch.where(valid, 0.0, NEG)[:, None, None, :]  # (R, 1 head, 1 query, K)
        ctx = self.cross(ve[:, None, :], h, key_bias)  # (R, 1, d)
        w2, b2 = self.head[0].weight, self.head[0].bias
        pre = F.linear(h, w2[:, :d]) + F.linear(ctx, w2[:, d:], b2)
        out = self.head[2](self.head[1](pre)).squeeze(-1)
        blend = pair[..., PAIR_BLEND].clamp(min=0.0)
        out = out + self.geo_scale * torch.log(blend + 1e-4)
        return torch.where(valid, out, torch.full_like(out, NEG))

    def forward(self, vert, bone, cand, pair):
        """Weights over the candidates (R, K), summing to 1 per row; 0 on pads."""
        return torch.softmax(self.logits(vert, bone, cand, pair), dim=-1)

    def num_params(self) -> int:
        return sum(p.numel() for p in self.parameters())


def loss_fn(logits, target, bone_key, dice_weight: float = 0.5, bone_norm: float = 0.5):
    """Cross-entropy to the artist's weights over the candidates, a soft Dice term on the
    active set (TokenRig), averaged half per vertex and half per bone (UniRig's skeletal
    equivalence: each bone's vertices count as much as any other bone's).

    target (R, K): artist weight of each candidate (rows may sum below 1: the rest lies on
    bones outside the candidates); bone_key (R,): a batch-unique id of each row's
    dominant artist bone. Rows with almost no artist weight on the candidates are skipped."""
    mass = target.sum(-1)
    keep = mass > 0.05
    t = target / mass.clamp(min=1e-6)[:, None]
    logp = torch.log_softmax(logits, dim=-1)
    p = logp.exp()
    ce = -(t * logp).sum(-1)
    dice = 1.0 - 2.0 * (p * t).sum(-1) / ((p * p).sum(-1) + (t * t).sum(-1)).clamp(min=1e-6)
    per_row = (ce + dice_weight * dice) * keep
    n = keep.sum().clamp(min=1)
    by_vertex = per_row.sum() / n
    # Per-bone means, then their mean.
    uniq, inv = torch.unique(bone_key, return_inverse=True)
    sums = torch.zeros(len(uniq)).index_add_(0, inv, per_row)
    cnts = torch.zeros(len(uniq)).index_add_(0, inv, keep.float())
    present = cnts > 0
    by_bone = (sums[present] / cnts[present]).mean() if bool(present.any()) else by_vertex
    return (1 - bone_norm) * by_vertex + bone_norm * by_bone


def sparsify(weights: torch.Tensor, cand: torch.Tensor, max_influences: int = 4, min_weight: float = 0.05):
    """What Rust does with the model's output: the largest `max_influences`, those under
    `min_weight` dropped (the largest always kept), renormalized. Returns (R, K) weights."""
    w = torch.where(cand >= 0, weights, torch.zeros_like(weights))
    k = min(max_influences, w.shape[-1])
    top = torch.topk(w, k, dim=-1)
    keep = torch.zeros_like(w).scatter(-1, top.indices, 1.0)
    first = torch.zeros_like(w).scatter(-1, top.indices[:, :1], 1.0)
    w = w * keep
    w = w / w.sum(-1, keepdim=True).clamp(min=1e-12)
    w = torch.where((w >= min_weight) | (first > 0), w, torch.zeros_like(w))
    return w / w.sum(-1, keepdim=True).clamp(min=1e-12)
