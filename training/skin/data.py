"""Reads the data sets written by `rigserve dataset --skin` (see src/dataset/skin.rs).

Features were computed in Rust (augmentation included); here we only draw items and a
random subset of their rows per step, and stack items into one batch whose bone table is
the items' bones back to back.
"""

from __future__ import annotations

import json
import os
from typing import List, Optional

import numpy as np
import torch

from .model import BONE_FEATURES, PAIR_FEATURES, VERT_FEATURES


class SkinDataset:
    """One `rigserve dataset --skin` output folder, memory-mapped."""

    def __init__(self, root: str, log=print):
        self.root = root
        with open(os.path.join(root, "index.jsonl")) as f:
            self.items = [json.loads(line) for line in f if line.strip()]
        if not self.items:
            raise ValueError(f"{root}: no items")
        ks = {it["k"] for it in self.items}
        if len(ks) != 1:
            raise ValueError(f"{root}: mixed candidate counts {sorted(ks)}")
        self.k = ks.pop()
        rows = sum(it["rows"] for it in self.items)
        bones = sum(it["bones"] for it in self.items)

        def mm(name, dtype, width):
            a = np.memmap(os.path.join(root, name), dtype=dtype, mode="r")
            if a.size != rows * width:
                raise ValueError(f"{root}/{name}: {a.size} values, expected {rows} rows x {width}")
            return a.reshape(rows, width)

        self.vert = mm("vert.f32", "<f4", VERT_FEATURES)
        self.pair = mm("pair.f32", "<f4", self.k * PAIR_FEATURES).reshape(rows, self.k, PAIR_FEATURES)
        self.cand = mm("cand.i32", "<i4", self.k)
        self.target = mm("target.f32", "<f4", self.k)
        b = np.memmap(os.path.join(root, "bone.f32"), dtype="<f4", mode="r")
        if b.size != bones * BONE_FEATURES:
            raise ValueError(f"{root}/bone.f32: {b.size} values, expected {bones} bones x {BONE_FEATURES}")
        self.bone = b.reshape(bones, BONE_FEATURES)
        log(f"[data] {root}: {len(self.items)} items, {rows} rows, {bones} bones, k={self.k}")

    def __len__(self):
        return len(self.items)

    def rows_of(self, i: int, rng: Optional[np.random.Generator], max_rows: int):
        it = self.items[i]
        lo, n = it["row_offset"], it["rows"]
        if rng is not None and n > max_rows:
            sel = lo + np.sort(rng.choice(n, size=max_rows, replace=False))
        else:
            sel = np.arange(lo, lo + min(n, max_rows))
        return sel


def collate(parts):
    """parts: list of (dataset, item index, row indices) -> batch tensors.

    Candidate indices are shifted into the stacked bone table; `bone_item` tells the
    bone attention which bones belong together; `bone_key` is each row's dominant artist
    bone, unique across the batch (for the per-bone loss average)."""
    verts, pairs, cands, targets, bones, bone_item, keys = [], [], [], [], [], [], []
    off = 0
    for j, (ds, i, sel) in enumerate(parts):
        it = ds.items[i]
        c = ds.cand[sel].astype(np.int64)
        t = np.asarray(ds.target[sel], dtype=np.float32)
        verts.append(np.asarray(ds.vert[sel]))
        pairs.append(np.asarray(ds.pair[sel]))
        dom = np.take_along_axis(c, t.argmax(-1)[:, None], -1)[:, 0]
        keys.append(np.where(dom >= 0, dom + off, -1))
        cands.append(np.where(c >= 0, c + off, -1))
        targets.append(t)
        b = np.asarray(ds.bone[it["bone_offset"]: it["bone_offset"] + it["bones"]])
        bones.append(b)
        bone_item.append(np.full(len(b), j, dtype=np.int64))
        off += len(b)
    cat = lambda xs: torch.from_numpy(np.ascontiguousarray(np.concatenate(xs)))
    return {
        "vert": cat(verts), "pair": cat(pairs), "cand": cat(cands), "target": cat(targets),
        "bone": cat(bones), "bone_item": cat(bone_item), "bone_key": cat(keys),
    }


class MixedSampler:
    """Items from several data sets with mixing weights (with replacement); numpy RNG
    state is saved in checkpoints."""

    def __init__(self, datasets: List[SkinDataset], weights: Optional[List[float]], seed: int):
        self.datasets = datasets
        w = np.asarray(weights if weights is not None else [len(d) for d in datasets], dtype=np.float64)
        if len(w) != len(datasets) or (w < 0).any() or w.sum() <= 0:
            raise ValueError("bad --mix weights")
        self.w = w / w.sum()
        self.rng = np.random.default_rng(seed)

    def batch(self, items: int, rows: int):
        parts = []
        for _ in range(items):
            ds = self.datasets[int(self.rng.choice(len(self.datasets), p=self.w))]
            i = int(self.rng.integers(len(ds)))
            parts.append((ds, i, ds.rows_of(i, self.rng, rows)))
        return collate(parts)

    def state(self):
        return self.rng.bit_generator.state

    def set_state(self, s):
        self.rng.bit_generator.state = s


def iterate_eval(ds: SkinDataset, items: int = 8, max_rows: int = 1 << 30):
    """Deterministic pass: every row of every item, `items` items per batch."""
    for s in range(0, len(ds), items):
        yield collate([(ds, i, ds.rows_of(i, None, max_rows)) for i in range(s, min(s + items, len(ds)))])
