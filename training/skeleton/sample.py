"""Decodes skeletons for a data set with a trained checkpoint, for quick sanity checks.

    python -m training.skeleton.sample --ckpt runs/skel/best.pt --data /tmp/ds_dev --out /tmp/dev_pred.jsonl

Greedy (default) or top-k sampling with a simplified version of the Rust grammar
(`src/rig/grammar.rs`, `Grammar::new`): every output parses. Writes one JSON line per item
(`file`, `aug`, `category`, `tokens` = the full decoded sequence from `<bos>`, `gt_tokens`,
`normalization`) so the Rust side can detokenize and score them, and prints a crude summary:
joint-count error and the symmetric joint-to-joint Chamfer distance in normalized units
(the rig scale is [-1, 1]), against the ground-truth tokens.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import List, Optional

import numpy as np
import torch

from . import model as M
from .data import SkeletonDataset

BODY_BONES, HAND_BONES = 22, 15


class SimpleGrammar:
    """Shape rules of the token grammar; branch parents must be positions of earlier joints
    and `<alt>` steps through earlier joints sharing the parent's cell. Enough to make every
    sampled sequence parse; the Rust grammar remains the reference."""

    def __init__(self, max_bones: int = 128, max_tokens: int = 512):
        self.max_bones, self.max_tokens = max_bones, max_tokens
        self.joints: List[tuple] = []
        self.state = "bos"
        self.n_tokens = 0
        self.chain = False  # the last joint can be continued
        self.templates_open = False
        self.hands = 0
        self.got: List[int] = []
        self.left = 0  # template joints left in the block
        self.alt_rank = 0
        self.alt_count = 0

    def _cell_count(self, cell):
        return sum(1 for j in self.joints if j == cell)

    def allowed(self) -> np.ndarray:
        m = np.zeros(M.VOCAB_SIZE, dtype=bool)
        s, n = self.state, len(self.joints)
        near_end = self.n_tokens + 8 >= self.max_tokens
        if s == "bos":
            m[M.BOS] = True
        elif s == "cls":
            m[M.CLS_BASE:M.CLS_BASE + len(M.CATEGORIES)] = True
        elif s == "boundary":
            if n > 0:
                m[M.EOS] = True
            if not near_end:
                room = n < self.max_bones
                if room and (n == 0 or self.chain):
                    m[:M.COORD_BINS] = True
                if room:
                    m[M.SPRING] = True
                    if n > 0:
                        m[M.BRANCH] = True
                if n == 0 and n + BODY_BONES <= self.max_bones:
                    m[M.MIXAMO_BODY] = True
                if self.templates_open and self.hands < 2 and n + HAND_BONES <= self.max_bones:
                    m[M.MIXAMO_HAND] = True
            if not m.any():
                m[M.EOS] = True
        elif s == "opened":
            m[M.BRANCH] = True
            for j in self.joints:
                m[j[0]] = True
        elif s == "parent":
            k = len(self.got)
            for j in self.joints:
                if list(j[:k]) == self.got:
                    m[j[k]] = True
        elif s == "alt":
            m[:M.COORD_BINS] = True
            if self.alt_rank + 1 < self.alt_count:
                m[M.ALT] = True
        elif s in ("joint", "template"):
            m[:M.COORD_BINS] = True
        else:  # done
            m[M.PAD] = True
        return m

    def advance(self, t: int):
        self.n_tokens += 1
        s = self.state
        if s == "bos":
            self.state = "cls"
        elif s == "cls":
            self.state = "boundary"
        elif s == "boundary":
            if t == M.EOS:
                self.state = "done"
            elif t == M.MIXAMO_BODY:
                self.state, self.left, self.got = "template", BODY_BONES, []
            elif t == M.MIXAMO_HAND:
                self.state, self.left, self.got = "template", HAND_BONES, []
                self.hands += 1
            elif t in (M.BRANCH, M.SPRING):
                self.state = "opened"
            else:
                self.state, self.got = "joint", [t]
        elif s == "opened":
            if t == M.BRANCH:
                self.state, self.got = "joint", []
            else:
                self.state, self.got = "parent", [t]
        elif s == "parent":
            self.got.append(t)
            if len(self.got) == 3:
                self.state, self.alt_rank = "alt", 0
                self.alt_count = max(1, self._cell_count(tuple(self.got)))
                self.got = []
        elif s == "alt":
            if t == M.ALT:
                self.alt_rank += 1
            else:
                self.state, self.got = "joint", [t]
        elif s == "joint":
            self.got.append(t)
            if len(self.got) == 3:
                self.joints.append(tuple(self.got))
                self.state, self.chain, self.templates_open = "boundary", True, False
        elif s == "template":
            self.got.append(t)
            if len(self.got) == 3:
                self.joints.append(tuple(self.got))
                self.got = []
                self.left -= 1
                if self.left == 0:
                    self.state, self.chain, self.templates_open = "boundary", False, True

    @property
    def done(self):
        return self.state == "done"


def joints_of(tokens) -> np.ndarray:
    g = SimpleGrammar(max_bones=10 ** 6, max_tokens=10 ** 6)
    for t in tokens:
        if g.done:
            break
        g.advance(int(t))
    q = np.array(g.joints, dtype=np.float32).reshape(-1, 3)
    return (q + 0.5) / M.COORD_BINS * 2 - 1


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    if len(a) == 0 or len(b) == 0:
        return float("nan")
    d = np.linalg.norm(a[:, None] - b[None], axis=-1)
    return float(0.5 * (d.min(1).mean() + d.min(0).mean()))


@torch.no_grad()
def decode(model: M.SkeletonModel, points: torch.Tensor, prompts: List[List[int]], top_k: int = 1,
           temperature: float = 1.0, max_bones: int = 128, gen: Optional[torch.Generator] = None):
    """Batched decoding with the KV cache (same call pattern as the ONNX decoder, no padding:
    all prompts have length 2)."""
    cfg = model.cfg
    b = points.shape[0]
    prefix = model.encoder(points)
    L = prefix.shape[1]
    gs = [SimpleGrammar(max_bones, cfg.max_tokens) for _ in range(b)]
    seqs = [list(p) for p in prompts]
    for g, p in zip(gs, prompts):
        for t in p:
            g.advance(t)
    t0 = len(prompts[0])
    assert all(len(p) == t0 for p in prompts)
    ids = torch.tensor(prompts, dtype=torch.int64)
    past = [(torch.zeros(b, cfg.n_heads, 0, cfg.head_dim), torch.zeros(b, cfg.n_heads, 0, cfg.head_dim)) for _ in model.decoder.layers]
    pos = torch.arange(L + t0).repeat(b, 1)
    mask = torch.ones(b, L + t0, dtype=torch.int64)
    logits, new = model.decoder.forward_cached(ids, prefix, pos, mask, past)
    past = M.append_past(past, new)
    n = t0
    while n < cfg.max_tokens and not all(g.done for g in gs):
        last = logits[:, -1].float()
        nxt = []
        for j, g in enumerate(gs):
            allowed = torch.from_numpy(g.allowed()[: last.shape[1]])
            lg = last[j].masked_fill(~allowed, float("-inf"))
            if top_k <= 1:
                t = int(lg.argmax())
            else:
                v, i = torch.topk(lg / temperature, min(top_k, int(allowed.sum())))
                t = int(i[torch.multinomial(torch.softmax(v, -1), 1, generator=gen)])
            g.advance(t)
            seqs[j].append(t)
            nxt.append(t)
        mask = torch.cat([mask, torch.ones(b, 1, dtype=torch.int64)], 1)
        logits, new = model.decoder.forward_cached(torch.tensor(nxt)[:, None], prefix[:, :0], torch.full((b, 1), L + n),
                                                   mask, past)
        past = M.append_past(past, new)
        n += 1
    return [s[: s.index(M.EOS) + 1] if M.EOS in s else s for s in seqs]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ckpt", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--points", type=int, default=2048)
    ap.add_argument("--top-k", type=int, default=1, help="1 = greedy")
    ap.add_argument("--temperature", type=float, default=1.0)
    ap.add_argument("--no-class", action="store_true", help="prompt with <cls:none> instead of the item's class")
    ap.add_argument("--limit", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    torch.set_num_threads(2)
    model, _ = M.load_model(a.ckpt)
    ds = SkeletonDataset(a.data, max_tokens=10 ** 9, log=lambda *x: print(*x, file=sys.stderr))
    n = len(ds) if not a.limit else min(a.limit, len(ds))
    gen = torch.Generator().manual_seed(a.seed)
    cd, jerr = [], []
    with open(a.out, "w") as f:
        for s in range(0, n, a.batch):
            ks = list(range(s, min(n, s + a.batch)))
            pts = torch.from_numpy(np.stack([ds.get(k)[0][: a.points] for k in ks]).astype(np.float32))
            gts = [ds.get(k)[1].tolist() for k in ks]
            prompts = [[M.BOS, M.CLS_NONE if a.no_class else gt[1]] for gt in gts]
            outs = decode(model, pts, prompts, a.top_k, a.temperature, gen=gen)
            for k, gt, o in zip(ks, gts, outs):
                it = ds.items[int(ds.keep[k])]
                pj, gj = joints_of(o), joints_of(gt)
                cd.append(chamfer(pj, gj))
                jerr.append(abs(len(pj) - len(gj)))
                f.write(json.dumps({"file": it.file, "aug": it.aug, "category": it.category, "tokens": o, "gt_tokens": gt,
                                    "joints_pred": len(pj), "joints_gt": len(gj), "j2j_chamfer": cd[-1]}) + "\n")
                print(f"{it.file} aug {it.aug}: joints {len(pj)} (gt {len(gj)}), j2j chamfer {cd[-1]:.4f}", file=sys.stderr)
    print(json.dumps({"items": n, "mean_j2j_chamfer": float(np.nanmean(cd)), "mean_abs_joint_count_error": float(np.mean(jerr))}))


if __name__ == "__main__":
    main()
