"""Trains the skin model on `rigserve dataset --skin` outputs.

    python -m training.skin.train --data /tmp/skin_train --data /tmp/skin_syn --mix 3,1 \
        --val /tmp/skin_dev --ckpt-dir /root/rigserve_runs/skin_v1 --steps 6000

Resumable: `--resume` continues from `<ckpt-dir>/last.pt` (model, optimizer, step, RNG
states). Logs to stdout and `<ckpt-dir>/log.csv`. `--val` is for monitoring only; the
exported checkpoint is the last one, so the dev split never picks the model.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import random
import sys
import time

import numpy as np
import torch

from .data import MixedSampler, SkinDataset, iterate_eval
from .model import SkinConfig, SkinModel, loss_fn, sparsify


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", action="append", required=True, help="dataset dir (repeatable)")
    ap.add_argument("--mix", default=None, help="comma-separated sampling weights, one per --data")
    ap.add_argument("--val", default=None, help="held-out dataset dir, for monitoring only")
    ap.add_argument("--ckpt-dir", required=True)
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--items", type=int, default=12, help="meshes per batch")
    ap.add_argument("--rows", type=int, default=384, help="vertex rows per mesh per batch")
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--min-lr-ratio", type=float, default=0.05)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--weight-decay", type=float, default=0.01)
    ap.add_argument("--clip", type=float, default=1.0)
    ap.add_argument("--dice", type=float, default=0.5)
    ap.add_argument("--bone-norm", type=float, default=0.5)
    ap.add_argument("--d", type=int, default=64)
    ap.add_argument("--heads", type=int, default=4)
    ap.add_argument("--bone-layers", type=int, default=1)
    ap.add_argument("--no-name-hints", action="store_true", help="ignore the bone name hints (ablation)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--log-every", type=int, default=25)
    ap.add_argument("--ckpt-every", type=int, default=200)
    ap.add_argument("--val-every", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    return ap.parse_args(argv)


def lr_at(step, a):
    if step < a.warmup:
        return a.lr * (step + 1) / a.warmup
    prog = min(1.0, (step - a.warmup) / max(1, a.steps - a.warmup))
    return a.lr * (a.min_lr_ratio + (1 - a.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * prog)))


@torch.no_grad()
def evaluate(model, ds):
    """Mean per-row L1 of the sparsified weights against the artist's (bones outside the
    candidates count as missed), like `rigserve eval`'s skin L1, and the same for the
    geometric blend the model starts from."""
    model.eval()
    l1, l1_geo, n = 0.0, 0.0, 0
    for b in iterate_eval(ds):
        w = sparsify(model(b["vert"], b["bone"], b["cand"], b["pair"]), b["cand"])
        geo = sparsify(b["pair"][..., 3], b["cand"])
        t = b["target"]
        miss = (1 - t.sum(-1)).clamp(min=0)
        l1 += float(((w - t).abs().sum(-1) + miss).sum())
        l1_geo += float(((geo - t).abs().sum(-1) + miss).sum())
        n += t.shape[0]
    model.train()
    return l1 / max(1, n), l1_geo / max(1, n)


def save_atomic(obj, path):
    tmp = path + ".tmp"
    torch.save(obj, tmp)
    os.replace(tmp, path)


def main(argv=None):
    sys.stdout.reconfigure(line_buffering=True)
    a = parse_args(argv)
    torch.set_num_threads(a.threads)
    os.makedirs(a.ckpt_dir, exist_ok=True)
    last_path = os.path.join(a.ckpt_dir, "last.pt")
    for d in a.data:
        if "dev" in os.path.basename(os.path.normpath(d)).lower():
            raise SystemExit(f"--data {d} looks like the dev split; never train on dev")
    resume = torch.load(last_path, map_location="cpu", weights_only=False) if a.resume and os.path.exists(last_path) else None
    cfg = (SkinConfig.from_dict(resume["config"]) if resume
           else SkinConfig(d=a.d, heads=a.heads, bone_layers=a.bone_layers, name_hints=not a.no_name_hints))
    random.seed(a.seed)
    np.random.seed(a.seed)
    torch.manual_seed(a.seed)
    datasets = [SkinDataset(d) for d in a.data]
    sampler = MixedSampler(datasets, [float(x) for x in a.mix.split(",")] if a.mix else None, seed=a.seed)
    val = SkinDataset(a.val) if a.val else None
    model = SkinModel(cfg)
    decay = [p for p in model.parameters() if p.dim() >= 2]
    other = [p for p in model.parameters() if p.dim() < 2]
    opt = torch.optim.AdamW([{"params": decay, "weight_decay": a.weight_decay}, {"params": other, "weight_decay": 0.0}],
                            lr=a.lr, betas=(0.9, 0.98))
    step = 0
    if resume:
        model.load_state_dict(resume["model"])
        opt.load_state_dict(resume["optimizer"])
        step = resume["step"]
        sampler.set_state(resume["sampler_rng"])
        torch.set_rng_state(resume["torch_rng"])
        random.setstate(resume["py_rng"])
        print(f"[train] resumed from {last_path} at step {step}")
    print(f"[train] config {cfg.to_dict()} params {model.num_params():,}")
    log_path = os.path.join(a.ckpt_dir, "log.csv")
    new_log = not (resume and os.path.exists(log_path))
    log_f = open(log_path, "w" if new_log else "a", newline="")
    log = csv.writer(log_f)
    if new_log:
        log.writerow(["step", "loss", "lr", "grad_norm", "steps_per_s", "val_l1", "val_l1_geometric", "elapsed_s"])

    def checkpoint(path):
        save_atomic({"config": cfg.to_dict(), "model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
                     "sampler_rng": sampler.state(), "torch_rng": torch.get_rng_state(), "py_rng": random.getstate(),
                     "args": vars(a)}, path)

    t0 = win_t = time.time()
    win_loss, win_steps = 0.0, 0
    model.train()
    while step < a.steps:
        lr = lr_at(step, a)
        for g in opt.param_groups:
            g["lr"] = lr
        b = sampler.batch(a.items, a.rows)
        logits = model.logits(b["vert"], b["bone"], b["cand"], b["pair"], b["bone_item"])
        loss = loss_fn(logits, b["target"], b["bone_key"], a.dice, a.bone_norm)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gn = torch.nn.utils.clip_grad_norm_(model.parameters(), a.clip)
        opt.step()
        step += 1
        win_loss += float(loss.detach())
        win_steps += 1
        val_l1 = val_geo = ""
        if val is not None and (step % a.val_every == 0 or step == a.steps):
            val_l1, val_geo = evaluate(model, val)
            print(f"[val] step {step} l1 {val_l1:.4f} (geometric {val_geo:.4f})")
        if step % a.log_every == 0 or step == a.steps or val_l1 != "":
            dt = time.time() - win_t
            row = [step, win_loss / max(1, win_steps), lr, float(gn), win_steps / dt, val_l1, val_geo, time.time() - t0]
            print(f"[train] step {step} loss {row[1]:.4f} lr {lr:.2e} gnorm {row[3]:.2f} steps/s {row[4]:.2f} "
                  f"geo_scale {float(model.geo_scale.detach()):.3f} elapsed {row[7]:.0f}s")
            log.writerow(row)
            log_f.flush()
            win_t, win_loss, win_steps = time.time(), 0.0, 0
        if step % a.ckpt_every == 0 or step == a.steps:
            checkpoint(last_path)
    log_f.close()
    print(f"[train] done at step {step}; checkpoint {last_path}")


if __name__ == "__main__":
    main()
