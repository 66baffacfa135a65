"""Checks exported ONNX files against the PyTorch model (see ONNX_CONTRACT.md).

    python -m training.skeleton.check_export --ckpt runs/skel/last.pt --onnx models/skeleton \
        [--data /tmp/ds_dev]

(a) encoder: onnxruntime vs PyTorch, max abs diff;
(b) decoder: greedy decoding of a batch of 2 with left padding, step by step with the KV
    cache, equals greedy decoding that recomputes the whole sequence each step (same tokens,
    logits within 1e-3), and equals PyTorch's teacher-forced logits;
(c) fp16/int8 variants (when present): drift of encoder output and logits vs fp32, and how
    many greedy tokens agree with fp32.
Exits non-zero when (a) or (b) fails.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Optional, Sequence

import numpy as np
import torch

from . import model as M

ENC_TOL = 1e-4
LOGIT_TOL = 1e-3


def session(path: str, threads: int = 2):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    return ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])


class OnnxSkeleton:
    """Minimal reference client of the contract: what the Rust server has to do."""

    def __init__(self, enc_path: str, dec_path: str, threads: int = 2):
        self.enc = session(enc_path, threads)
        self.dec = session(dec_path, threads)
        meta = self.dec.get_modelmeta().custom_metadata_map
        self.n_layers = int(meta["n_layers"])
        self.n_heads = int(meta["n_heads"])
        self.head_dim = int(meta["head_dim"])
        self.d_model = int(meta["d_model"])
        self.n_latents = int(meta["n_latents"])

    def encode(self, points: np.ndarray) -> np.ndarray:
        return self.enc.run(["prefix"], {"points": points.astype(np.float32)})[0]

    def empty_past(self, b: int):
        z = np.zeros((b, self.n_heads, 0, self.head_dim), dtype=np.float32)
        return [z] * (2 * self.n_layers)

    def run_decoder(self, input_ids, prefix, position_ids, attention_mask, past):
        """(logits, new keys/values of this call's positions), layer 0 key first."""
        feeds = {"input_ids": input_ids.astype(np.int64), "prefix": prefix.astype(np.float32),
                 "position_ids": position_ids.astype(np.int64), "attention_mask": attention_mask.astype(np.int64)}
        for i in range(self.n_layers):
            feeds[f"past_key_values.{i}.key"] = past[2 * i]
            feeds[f"past_key_values.{i}.value"] = past[2 * i + 1]
        out = self.dec.run(None, feeds)
        return out[0], out[1:]


def append_past(past, new):
    """`skeleton-v2` returns only the new positions' keys and values: the client keeps
    the cache and appends them (along the sequence axis) for the next call."""
    return [np.concatenate([p, n], axis=2) for p, n in zip(past, new)]


def left_pad(prompts: Sequence[Sequence[int]], n_latents: int):
    """input_ids, position_ids (prefix included) and attention_mask for a prefill call."""
    b, t = len(prompts), max(len(p) for p in prompts)
    ids = np.full((b, t), M.PAD, dtype=np.int64)
    mask = np.zeros((b, n_latents + t), dtype=np.int64)
    pos = np.zeros((b, n_latents + t), dtype=np.int64)
    mask[:, :n_latents] = 1
    pos[:, :n_latents] = np.arange(n_latents)
    for j, p in enumerate(prompts):
        pad = t - len(p)
        ids[j, pad:] = p
        mask[j, n_latents + pad:] = 1
        pos[j, n_latents:] = n_latents  # padding slots: any valid position, they are masked out
        pos[j, n_latents + pad:] = n_latents + np.arange(len(p))
    return ids, pos, mask


def greedy_cached(m: OnnxSkeleton, prefix: np.ndarray, prompts, steps: int):
    """Prefill once, then one token per call with the KV cache. Returns tokens (B, steps)
    and the logits that chose them (B, steps, V)."""
    b = prefix.shape[0]
    ids, pos, mask = left_pad(prompts, prefix.shape[1])
    past = m.empty_past(b)
    logits, new = m.run_decoder(ids, prefix, pos, mask, past)
    past = append_past(past, new)
    next_pos = np.array([prefix.shape[1] + len(p) for p in prompts], dtype=np.int64)
    toks, lgs = [], []
    empty_prefix = np.zeros((b, 0, prefix.shape[2]), dtype=np.float32)
    for s in range(steps):
        last = logits[:, -1]
        nxt = last.argmax(-1)
        toks.append(nxt)
        lgs.append(last)
        if s == steps - 1:
            break
        mask = np.concatenate([mask, np.ones((b, 1), dtype=np.int64)], axis=1)
        logits, new = m.run_decoder(nxt[:, None], empty_prefix, next_pos[:, None], mask, past)
        past = append_past(past, new)
        next_pos = next_pos + 1
    return np.stack(toks, 1), np.stack(lgs, 1)


def greedy_recompute(m: OnnxSkeleton, prefix: np.ndarray, prompts, steps: int):
    """Greedy decoding without a cache: the whole (left-padded) sequence every step."""
    seqs = [list(p) for p in prompts]
    b = prefix.shape[0]
    toks, lgs = [], []
    for _ in range(steps):
        ids, pos, mask = left_pad(seqs, prefix.shape[1])
        logits, _ = m.run_decoder(ids, prefix, pos, mask, m.empty_past(b))
        last = logits[:, -1]
        nxt = last.argmax(-1)
        toks.append(nxt)
        lgs.append(last)
        for j in range(b):
            seqs[j].append(int(nxt[j]))
    return np.stack(toks, 1), np.stack(lgs, 1)


@torch.no_grad()
def torch_logits(model: M.SkeletonModel, prefix: torch.Tensor, prompts, tokens: np.ndarray):
    """PyTorch teacher-forced logits (training path, no padding) at the positions that chose
    each generated token. (B, steps, V)"""
    out = []
    for j, p in enumerate(prompts):
        seq = torch.tensor([list(p) + tokens[j, :-1].tolist()], dtype=torch.int64)
        lg = model.decoder.forward_train(prefix[j:j + 1], seq)[0]
        out.append(lg[len(p) - 1:].numpy())
    return np.stack(out)


def sample_inputs(cfg: M.ModelConfig, data: Optional[str], n_points: int, seed: int = 0):
    """Two items (points + prompts of different lengths, to exercise left padding)."""
    rng = np.random.default_rng(seed)
    if data:
        from .data import SkeletonDataset

        ds = SkeletonDataset(data, max_tokens=10 ** 9, log=lambda *_: None)
        idx = [0, min(1, len(ds) - 1)]
        pts = np.stack([ds.get(i)[0][:n_points] for i in idx]).astype(np.float32)
        t0, t1 = ds.get(idx[0])[1], ds.get(idx[1])[1]
        prompts = [t0[:2].tolist(), t1[: min(len(t1) - 1, 6)].tolist()]
    else:
        xyz = rng.uniform(-1, 1, (2, n_points, 3))
        nrm = rng.normal(size=(2, n_points, 3))
        nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
        pts = np.concatenate([xyz, nrm], -1).astype(np.float32)
        prompts = [[M.BOS, M.CLS_NONE], [M.BOS, M.CLS_BASE + 1, 120, 130, 140]]
    return pts, prompts


def check(model: M.SkeletonModel, onnx_dir: str, data: Optional[str] = None, steps: int = 24, n_points: int = 2048,
          variants=("fp16", "int8"), threads: int = 2) -> dict:
    model = model.float().eval()
    cfg = model.cfg
    res: dict = {}
    m = OnnxSkeleton(os.path.join(onnx_dir, "encoder.onnx"), os.path.join(onnx_dir, "decoder.onnx"), threads)
    pts, prompts = sample_inputs(cfg, data, n_points)

    # (a) encoder, at two point counts and batch sizes
    with torch.no_grad():
        ref_prefix = model.encoder(torch.from_numpy(pts))
    prefix = m.encode(pts)
    res["encoder_max_abs_diff"] = float(np.abs(prefix - ref_prefix.numpy()).max())
    with torch.no_grad():
        ref1 = model.encoder(torch.from_numpy(pts[:1, :777])).numpy()
    res["encoder_max_abs_diff_b1_n777"] = float(np.abs(m.encode(pts[:1, :777]) - ref1).max())
    res["encoder_ok"] = max(res["encoder_max_abs_diff"], res["encoder_max_abs_diff_b1_n777"]) <= ENC_TOL

    # (b) decoder: cache vs recompute vs PyTorch
    tc, lc = greedy_cached(m, prefix, prompts, steps)
    tr, lr = greedy_recompute(m, prefix, prompts, steps)
    tt = torch_logits(model, ref_prefix, prompts, tc)
    res["prompts"] = [list(map(int, p)) for p in prompts]
    res["greedy_tokens"] = tc.tolist()
    res["cache_vs_recompute_same_tokens"] = bool((tc == tr).all())
    res["cache_vs_recompute_max_logit_diff"] = float(np.abs(lc - lr).max())
    res["cache_vs_torch_max_logit_diff"] = float(np.abs(lc - tt).max())
    res["torch_greedy_agrees"] = bool((tt.argmax(-1) == tc).all())
    res["decoder_ok"] = (res["cache_vs_recompute_same_tokens"] and res["torch_greedy_agrees"]
                         and res["cache_vs_recompute_max_logit_diff"] <= LOGIT_TOL
                         and res["cache_vs_torch_max_logit_diff"] <= LOGIT_TOL)

    # (c) variants
    for v in variants:
        enc_p, dec_p = (os.path.join(onnx_dir, f"{n}.{v}.onnx") for n in ("encoder", "decoder"))
        if not (os.path.exists(enc_p) and os.path.exists(dec_p)):
            continue
        mv = OnnxSkeleton(enc_p, dec_p, threads)
        pv = mv.encode(pts)
        # teacher-forced on the fp32 tokens: logit drift at the same positions
        lv_tf = _teacher_forced(mv, pv, prompts, tc)
        tv, _ = greedy_cached(mv, pv, prompts, steps)
        agree = [int(np.argmax(np.append(tv[j] != tc[j], True))) for j in range(len(prompts))]
        res[v] = {
            "encoder_max_abs_diff": float(np.abs(pv - prefix).max()),
            "logits_max_abs_diff": float(np.abs(lv_tf - lc).max()),
            "logits_mean_abs_diff": float(np.abs(lv_tf - lc).mean()),
            "teacher_forced_argmax_agreement": float((lv_tf.argmax(-1) == tc).mean()),
            "greedy_tokens_equal_prefix_len": agree,
            "steps": steps,
            "size_mb": round((os.path.getsize(enc_p) + os.path.getsize(dec_p)) / 1e6, 2),
        }
    res["ok"] = res["encoder_ok"] and res["decoder_ok"]
    return res


def _teacher_forced(m: OnnxSkeleton, prefix, prompts, tokens):
    """One prefill call over prompt + given tokens; logits at the positions that predict them."""
    seqs = [list(p) + tokens[j, :-1].tolist() for j, p in enumerate(prompts)]
    ids, pos, mask = left_pad(seqs, prefix.shape[1])
    logits, _ = m.run_decoder(ids, prefix, pos, mask, m.empty_past(prefix.shape[0]))
    return logits[:, -tokens.shape[1]:]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ckpt", required=True)
    ap.add_argument("--onnx", required=True, help="folder with encoder.onnx / decoder.onnx (+ variants)")
    ap.add_argument("--data", default=None, help="dataset dir to take 2 items from (e.g. the dev split); random points if absent")
    ap.add_argument("--steps", type=int, default=24)
    ap.add_argument("--points", type=int, default=2048)
    a = ap.parse_args(argv)
    torch.set_num_threads(2)
    model, _ = M.load_model(a.ckpt)
    res = check(model, a.onnx, a.data, a.steps, a.points)
    print(json.dumps(res, indent=2))
    sys.exit(0 if res["ok"] else 1)


if __name__ == "__main__":
    main()
