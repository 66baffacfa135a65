"""Reads the data sets written by `rigserve dataset` (points.f32 + index.jsonl).

Geometry augmentation already happened in Rust; here we only pick a random subset of each
item's surface samples per step and (optionally) hide the class token.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np
import torch

from .model import CLS_BASE, CLS_NONE, PAD, VOCAB_SIZE


@dataclass
class Item:
    tokens: np.ndarray  # int64
    file: str
    category: str
    aug: int


class SkeletonDataset:
    """One `rigserve dataset` output folder. Points are memory-mapped."""

    def __init__(self, root: str, max_tokens: int = 512, log=print):
        self.root = root
        items: List[Item] = []
        with open(os.path.join(root, "index.jsonl")) as f:
            for line in f:
                if line.strip():
                    j = json.loads(line)
                    items.append(Item(np.asarray(j["tokens"], dtype=np.int64), j["file"], j.get("category", ""), j.get("aug", 0)))
        n_items = len(items)
        raw = np.memmap(os.path.join(root, "points.f32"), dtype="<f4", mode="r")
        if n_items == 0 or raw.size % (n_items * 6) != 0:
            raise ValueError(f"{root}: points.f32 has {raw.size} floats, not divisible by {n_items} items x 6")
        self.n_points = raw.size // (n_items * 6)
        self.points = raw.reshape(n_items, self.n_points, 6)
        for it in items:
            t = it.tokens
            if t.min() < 0 or t.max() >= VOCAB_SIZE:
                raise ValueError(f"{root}: token out of range in {it.file}")
        keep = [i for i, it in enumerate(items) if len(it.tokens) <= max_tokens]
        self.dropped = n_items - len(keep)
        self.items = items
        self.keep = np.asarray(keep, dtype=np.int64)
        lens = np.array([len(items[i].tokens) for i in keep]) if keep else np.zeros(1)
        log(
            f"[data] {root}: {n_items} items, {self.n_points} points/item, kept {len(keep)}, "
            f"dropped {self.dropped} longer than {max_tokens} tokens; tokens mean {lens.mean():.0f} max {lens.max()}"
        )

    def __len__(self):
        return len(self.keep)

    def get(self, k: int):
        i = int(self.keep[k])
        return self.points[i], self.items[i].tokens


def collate(points_list: Sequence[np.ndarray], tokens_list: Sequence[np.ndarray], n_points: int, rng: np.random.Generator,
            cls_drop: float = 0.0, subset: bool = True):
    """Batch: random subset of `n_points` samples per item (without replacement) and tokens
    right-padded with <pad>. With probability `cls_drop` the class token becomes <cls:none>."""
    b = len(points_list)
    pts = np.empty((b, n_points, 6), dtype=np.float32)
    for j, p in enumerate(points_list):
        if subset and n_points < p.shape[0]:
            idx = rng.choice(p.shape[0], size=n_points, replace=False)
            pts[j] = p[np.sort(idx)]
        else:
            pts[j] = p[:n_points]
    t = max(len(x) for x in tokens_list)
    ids = np.full((b, t), PAD, dtype=np.int64)
    for j, x in enumerate(tokens_list):
        ids[j, : len(x)] = x
        if cls_drop > 0 and len(x) > 1 and CLS_BASE <= x[1] < VOCAB_SIZE and rng.random() < cls_drop:
            ids[j, 1] = CLS_NONE
    return torch.from_numpy(pts), torch.from_numpy(ids)


class MixedSampler:
    """Draws batches from several data sets with given mixing weights (items sampled with
    replacement; the state lives in a numpy Generator, saved in checkpoints).

    Length bucketing: `pool` batches' worth of items are drawn at once, sorted by token
    length and cut into batches served in random order. Each item is still drawn uniformly
    (within its data set), but a batch pads to a similar length, which roughly halves the
    decoder's work on this data (median 80 tokens, max 310)."""

    def __init__(self, datasets: List[SkeletonDataset], weights: Optional[List[float]], seed: int, pool: int = 8):
        self.datasets = datasets
        if weights is None:
            weights = [len(d) for d in datasets]
        w = np.asarray(weights, dtype=np.float64)
        if len(w) != len(datasets) or (w < 0).any() or w.sum() <= 0:
            raise ValueError("bad --mix weights")
        for d, wi in zip(datasets, w):
            if wi > 0 and len(d) == 0:
                raise ValueError(f"{d.root}: no usable items")
        self.w = w / w.sum()
        self.rng = np.random.default_rng(seed)
        self.pool = max(1, pool)
        self.queue: List[list] = []
        self.min_points = min(d.n_points for d in datasets)

    def _refill(self, batch_size: int):
        n = batch_size * self.pool
        which = self.rng.choice(len(self.datasets), size=n, p=self.w)
        picks = [(int(di), int(self.rng.integers(len(self.datasets[di])))) for di in which]
        picks.sort(key=lambda x: len(self.datasets[x[0]].get(x[1])[1]))
        batches = [picks[i:i + batch_size] for i in range(0, n, batch_size)]
        order = self.rng.permutation(len(batches))
        self.queue = [batches[i] for i in order]

    def batch(self, batch_size: int, n_points: int, cls_drop: float):
        n_points = min(n_points, self.min_points)
        if not self.queue or len(self.queue[0]) != batch_size:
            self._refill(batch_size)
        picks = self.queue.pop(0)
        pts, toks = [], []
        for di, k in picks:
            p, t = self.datasets[di].get(k)
            pts.append(p)
            toks.append(t)
        return collate(pts, toks, n_points, self.rng, cls_drop=cls_drop)

    def state(self):
        return {"rng": self.rng.bit_generator.state, "queue": self.queue}

    def set_state(self, s):
        self.rng.bit_generator.state = s["rng"]
        self.queue = [list(map(tuple, b)) for b in s["queue"]]


def iterate_eval(ds: SkeletonDataset, batch_size: int, n_points: Optional[int] = None, cls_none: bool = False):
    """Deterministic pass over a data set (first `n_points` samples of each item)."""
    n_points = ds.n_points if n_points is None else min(n_points, ds.n_points)
    rng = np.random.default_rng(0)
    for s in range(0, len(ds), batch_size):
        pts, toks = [], []
        for k in range(s, min(s + batch_size, len(ds))):
            p, t = ds.get(k)
            pts.append(p)
            toks.append(t)
        yield collate(pts, toks, n_points, rng, cls_drop=1.0 if cls_none else 0.0, subset=False)
