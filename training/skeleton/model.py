"""Skeleton model: a Perceiver-style point encoder and a decoder-only transformer.

The module layout mirrors what the Rust server runs (see ONNX_CONTRACT.md):

* ``PointEncoder``   -> ``encoder.onnx``: points (B, N, 6) -> prefix (B, L, d)
* ``SkeletonDecoder`` -> ``decoder.onnx``: [prefix ; token embeddings] through a causal
  transformer with a KV cache, logits only for the token positions.

``SkeletonModel`` ties both together for training (``forward`` = teacher-forced logits).
All attention uses finite additive masks (-1e9) so that exported graphs never produce NaN.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import List, Optional, Tuple

import torch
import torch.nn as nn
import torch.nn.functional as F

# Vocabulary (src/rig/tokenizer.rs; ids are baked into trained models).
COORD_BINS = 256
BOS = 256
EOS = 257
PAD = 258
BRANCH = 259
SPRING = 260
MIXAMO_BODY = 261
MIXAMO_HAND = 262
CLS_BASE = 263
CATEGORIES = [
    "none",
    "humanoid",
    "humanoid_creature",
    "quadruped",
    "bird_flyer",
    "insect_spider",
    "fish_snake_tail",
    "other_creature",
    "robot_prop",
]
CLS_NONE = CLS_BASE
# `<alt>` (src/rig/tokenizer.rs) picks among earlier joints sharing a branch parent's cell;
# it was appended after the class tokens, so the vocabulary is 273.
ALT = CLS_BASE + len(CATEGORIES)  # 272
VOCAB_SIZE = ALT + 1  # 273

NEG_INF = -1e9


def class_token(category: Optional[str]) -> int:
    if category is None:
        return CLS_NONE
    c = category.strip().lower()
    return CLS_BASE + CATEGORIES.index(c) if c in CATEGORIES else CLS_NONE


@dataclass
class ModelConfig:
    d_model: int = 256
    n_heads: int = 8
    # encoder
    n_latents: int = 128
    n_freqs: int = 8
    enc_self_layers: int = 2
    # decoder
    dec_layers: int = 6
    d_ff: int = 1024
    max_tokens: int = 512
    vocab_size: int = VOCAB_SIZE
    tie_embeddings: bool = False
    dropout: float = 0.0

    @property
    def max_positions(self) -> int:
        return self.n_latents + self.max_tokens

    @property
    def head_dim(self) -> int:
        return self.d_model // self.n_heads

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "ModelConfig":
        known = {f for f in ModelConfig.__dataclass_fields__}
        return ModelConfig(**{k: v for k, v in d.items() if k in known})


def tiny_config(**kw) -> ModelConfig:
    """A small configuration for tests and smoke runs."""
    base = dict(d_model=64, n_heads=4, n_latents=32, n_freqs=6, enc_self_layers=1, dec_layers=2, d_ff=256)
    base.update(kw)
    return ModelConfig(**base)


# ---------------------------------------------------------------------------------------------
# Building blocks


class FeedForward(nn.Module):
    def __init__(self, d: int, d_ff: int, dropout: float):
        super().__init__()
        self.fc1 = nn.Linear(d, d_ff)
        self.fc2 = nn.Linear(d_ff, d)
        self.drop = nn.Dropout(dropout)

    def forward(self, x):
        # tanh GELU: exports to plain ops under every exporter and opset.
        return self.drop(self.fc2(F.gelu(self.fc1(x), approximate="tanh")))


def _attend(q, k, v, bias: Optional[torch.Tensor], causal: bool):
    """q (B,H,Tq,dh), k/v (B,H,Tk,dh); bias additive (broadcastable to B,H,Tq,Tk) or None."""
    if bias is None:
        return F.scaled_dot_product_attention(q, k, v, is_causal=causal)
    scale = 1.0 / math.sqrt(q.shape[-1])
    att = torch.matmul(q, k.transpose(-1, -2)) * scale + bias
    att = torch.softmax(att, dim=-1)
    return torch.matmul(att, v)


class MultiHeadAttention(nn.Module):
    """Self- or cross-attention with separate q/k/v projections."""

    def __init__(self, d: int, n_heads: int, d_kv: Optional[int] = None, dropout: float = 0.0):
        super().__init__()
        assert d % n_heads == 0
        self.h = n_heads
        self.dh = d // n_heads
        d_kv = d if d_kv is None else d_kv
        self.q = nn.Linear(d, d)
        self.k = nn.Linear(d_kv, d)
        self.v = nn.Linear(d_kv, d)
        self.o = nn.Linear(d, d)
        self.drop = nn.Dropout(dropout)

    def split(self, x):
        b, t, _ = x.shape
        return x.view(b, t, self.h, self.dh).transpose(1, 2)

    def merge(self, x):
        b, h, t, dh = x.shape
        return x.transpose(1, 2).reshape(b, t, h * dh)

    def forward(self, x, kv=None, causal=False):
        kv = x if kv is None else kv
        q, k, v = self.split(self.q(x)), self.split(self.k(kv)), self.split(self.v(kv))
        return self.drop(self.o(self.merge(_attend(q, k, v, None, causal))))


class EncoderBlock(nn.Module):
    """Pre-LN block: (cross- or self-) attention then FFN."""

    def __init__(self, d: int, n_heads: int, d_ff: int, dropout: float, cross: bool):
        super().__init__()
        self.cross = cross
        self.ln_q = nn.LayerNorm(d)
        self.ln_kv = nn.LayerNorm(d) if cross else None
        self.attn = MultiHeadAttention(d, n_heads, dropout=dropout)
        self.ln_ff = nn.LayerNorm(d)
        self.ff = FeedForward(d, d_ff, dropout)

    def forward(self, x, ctx=None):
        if self.cross:
            x = x + self.attn(self.ln_q(x), self.ln_kv(ctx))
        else:
            x = x + self.attn(self.ln_q(x))
        return x + self.ff(self.ln_ff(x))


class PointEncoder(nn.Module):
    """3DShape2VecSet / Perceiver style: Fourier(xyz) + normal -> d, L learned queries
    cross-attend to the N points, then self-attention over the latents.

    Input ``points`` (B, N, 6): xyz in [-1, 1] then a unit normal. Output (B, L, d).
    Permutation invariant in the points and defined for any N >= 1.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        d = cfg.d_model
        self.register_buffer(
            "freqs", (2.0 ** torch.arange(cfg.n_freqs, dtype=torch.float32)) * math.pi, persistent=False
        )
        in_dim = 3 + 3 + 3 * cfg.n_freqs * 2
        self.inp = nn.Linear(in_dim, d)
        self.latents = nn.Parameter(torch.randn(cfg.n_latents, d) * 0.02)
        self.cross = EncoderBlock(d, cfg.n_heads, cfg.d_ff, cfg.dropout, cross=True)
        self.selfs = nn.ModuleList(
            [EncoderBlock(d, cfg.n_heads, cfg.d_ff, cfg.dropout, cross=False) for _ in range(cfg.enc_self_layers)]
        )
        self.ln_out = nn.LayerNorm(d)

    def embed_points(self, points):
        xyz, nrm = points[..., :3], points[..., 3:6]
        proj = (xyz.unsqueeze(-1) * self.freqs).flatten(-2)  # (B, N, 3*F)
        feats = torch.cat([xyz, nrm, torch.sin(proj), torch.cos(proj)], dim=-1)
        return self.inp(feats)

    def forward(self, points):
        ctx = self.embed_points(points)
        x = self.latents.unsqueeze(0).expand(points.shape[0], -1, -1)
        x = self.cross(x, ctx)
        for blk in self.selfs:
            x = blk(x)
        return self.ln_out(x)


class DecoderLayer(nn.Module):
    def __init__(self, cfg: ModelConfig):
        super().__init__()
        d = cfg.d_model
        self.ln1 = nn.LayerNorm(d)
        self.attn = MultiHeadAttention(d, cfg.n_heads, dropout=cfg.dropout)
        self.ln2 = nn.LayerNorm(d)
        self.ff = FeedForward(d, cfg.d_ff, cfg.dropout)

    def forward(self, x, bias=None, past: Optional[Tuple[torch.Tensor, torch.Tensor]] = None):
        """Training: ``bias`` None, ``past`` None, plain causal attention; returns (x, None).

        Cached (``skeleton-v2``): ``bias`` is (bias_past, bias_new), additive masks of shape
        (B, 1, S, past) and (B, 1, S, S); returns (x, (key, value)) of the S new positions
        only. The past is read where it lies and never concatenated with the new keys: a
        concat would copy the whole cache every step (the cost ``skeleton-v1`` paid), and
        the caller appends the new rows into a buffer it keeps in place."""
        a = self.attn
        h = self.ln1(x)
        q, k, v = a.split(a.q(h)), a.split(a.k(h)), a.split(a.v(h))
        if past is None:
            o = _attend(q, k, v, None, causal=True)
        else:
            o = _attend_split(q, past, (k, v), bias)
        x = x + a.drop(a.o(a.merge(o)))
        x = x + self.ff(self.ln2(x))
        return x, (None if past is None else (k, v))


def _attend_split(q, past, new, bias):
    """Attention over [past ; new] without materialising the concatenation of keys and
    values: scores against each part, one softmax over both, then the two weighted sums.
    Only the score rows (B, H, S, past + S) are concatenated, which is small."""
    (pk, pv), (nk, nv), (bp, bn) = past, new, bias
    scale = 1.0 / math.sqrt(q.shape[-1])
    sp = torch.matmul(q, pk.transpose(-1, -2)) * scale + bp
    sn = torch.matmul(q, nk.transpose(-1, -2)) * scale + bn
    att = torch.softmax(torch.cat([sp, sn], dim=-1), dim=-1)
    n_past = pk.shape[2]
    return torch.matmul(att[..., :n_past], pv) + torch.matmul(att[..., n_past:], nv)


def append_past(past, new):
    """The next call's past: each layer's new keys and values appended to its old ones
    (what a reference client does; the Rust server writes into a preallocated buffer)."""
    return [(torch.cat([pk, nk], 2), torch.cat([pv, nv], 2)) for (pk, pv), (nk, nv) in zip(past, new)]


class SkeletonDecoder(nn.Module):
    """Decoder-only transformer over [prefix ; tokens] with learned absolute positions."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        d = cfg.d_model
        self.tok = nn.Embedding(cfg.vocab_size, d)
        self.pos = nn.Embedding(cfg.max_positions, d)
        self.layers = nn.ModuleList([DecoderLayer(cfg) for _ in range(cfg.dec_layers)])
        self.ln_f = nn.LayerNorm(d)
        self.head = nn.Linear(d, cfg.vocab_size, bias=False)
        if cfg.tie_embeddings:
            self.head.weight = self.tok.weight
        self.drop = nn.Dropout(cfg.dropout)

    # -- training path: full causal attention, no cache, right padding (ignored by the loss)
    def forward_train(self, prefix, input_ids):
        b, p, _ = prefix.shape
        t = input_ids.shape[1]
        x = torch.cat([prefix, self.tok(input_ids)], dim=1)
        x = self.drop(x + self.pos.weight[: p + t].unsqueeze(0))
        for layer in self.layers:
            x, _ = layer(x)
        x = self.ln_f(x[:, p:])
        return self.head(x)

    # -- inference path (exported): KV cache, left padding, explicit positions
    def forward_cached(
        self,
        input_ids: torch.Tensor,  # (B, T) int64
        prefix: torch.Tensor,  # (B, P, d), P = L (prefill) or 0 (decode)
        position_ids: torch.Tensor,  # (B, P+T) int64
        attention_mask: torch.Tensor,  # (B, past+P+T) int64, 1 real / 0 padding
        past: List[Tuple[torch.Tensor, torch.Tensor]],  # per layer (B, H, past, dh)
    ):
        """Logits (B, T, V) of the token positions and, per layer, the keys and values of
        the P + T new positions only (``skeleton-v2``; see ONNX_CONTRACT.md)."""
        p = prefix.shape[1]
        past_len = past[0][0].shape[2]
        x = torch.cat([prefix, self.tok(input_ids)], dim=1)  # (B, S, d), S = P+T
        s = x.shape[1]
        x = x + self.pos(position_ids)
        # Additive masks. Past slots precede every new position, so only the mask decides
        # what of the past is seen (unwritten capacity and left padding are 0); new
        # positions are causal among themselves and masked by their own mask columns.
        zero = torch.zeros((), dtype=x.dtype, device=x.device)
        neg = torch.full((), NEG_INF, dtype=x.dtype, device=x.device)
        real = attention_mask != 0  # (B, past+S)
        bias_past = torch.where(real[:, :past_len], zero, neg)[:, None, None, :]  # (B,1,1,past)
        q_idx = torch.arange(s, device=x.device).unsqueeze(1)
        causal = torch.arange(s, device=x.device).unsqueeze(0) <= q_idx  # (S, S)
        keep_new = causal.unsqueeze(0) & real[:, past_len:].unsqueeze(1)  # (B, S, S)
        bias_new = torch.where(keep_new, zero, neg).unsqueeze(1)
        new_kv = []
        for layer, kv in zip(self.layers, past):
            x, kv_new = layer(x, (bias_past, bias_new), kv)
            new_kv.append(kv_new)
        x = self.ln_f(x[:, p:])
        return self.head(x), new_kv


class SkeletonModel(nn.Module):
    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = PointEncoder(cfg)
        self.decoder = SkeletonDecoder(cfg)
        self.apply(self._init)

    @staticmethod
    def _init(m):
        if isinstance(m, nn.Linear):
            nn.init.normal_(m.weight, std=0.02)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.Embedding):
            nn.init.normal_(m.weight, std=0.02)

    def forward(self, points, input_ids):
        """Teacher forcing: logits (B, T, V) for each token position of ``input_ids``."""
        return self.decoder.forward_train(self.encoder(points), input_ids)

    def num_params(self) -> dict:
        def count(m):
            return sum(p.numel() for p in m.parameters())

        return {"encoder": count(self.encoder), "decoder": count(self.decoder), "total": count(self)}


def loss_fn(logits, input_ids, ignore_class_target: bool = True, coord_sigma: float = 0.0):
    """Next-token cross-entropy over token positions; padding ignored. The class token
    (position 1) is an input hint, not a prediction target.

    ``coord_sigma`` > 0 (in bins) replaces the one-hot target of a coordinate token by a
    Gaussian over the neighbouring bins. Plain cross-entropy scores a joint one bin off as
    wrong as one across the body, so nothing in the loss says which mistakes cost
    distance; the smoothed target does, and its minimum is still at the right bin."""
    targets = input_ids[:, 1:].clone()
    targets[targets == PAD] = -100
    if ignore_class_target:
        targets[:, 0] = -100
    lg = logits[:, :-1].float()
    flat_t = targets.reshape(-1)
    flat_lg = lg.reshape(-1, lg.shape[-1])
    count = (targets != -100).sum()
    if coord_sigma <= 0:
        return F.cross_entropy(flat_lg, flat_t, ignore_index=-100, reduction="sum"), count
    is_coord = (flat_t >= 0) & (flat_t < COORD_BINS)
    other = flat_t.masked_fill(is_coord, -100)
    loss = F.cross_entropy(flat_lg, other, ignore_index=-100, reduction="sum")
    if bool(is_coord.any()):
        logp = F.log_softmax(flat_lg[is_coord], dim=-1)
        bins = torch.arange(COORD_BINS, device=lg.device, dtype=torch.float32)
        d = bins[None, :] - flat_t[is_coord].float()[:, None]
        soft = torch.exp(-0.5 * (d / coord_sigma) ** 2)
        soft = soft / soft.sum(dim=1, keepdim=True)
        loss = loss - (soft * logp[:, :COORD_BINS]).sum()
    return loss, count


def save_checkpoint(path, model, cfg, **extra):
    torch.save({"config": cfg.to_dict(), "model": model.state_dict(), **extra}, path)


def load_model(path, map_location="cpu") -> Tuple[SkeletonModel, dict]:
    ck = torch.load(path, map_location=map_location, weights_only=False)
    cfg = ModelConfig.from_dict(ck["config"])
    m = SkeletonModel(cfg)
    m.load_state_dict(ck["model"])
    m.eval()
    return m, ck
