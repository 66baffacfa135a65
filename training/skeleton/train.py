"""Trains the skeleton model on `rigserve dataset` outputs.

    python -m training.skeleton.train --data /tmp/ds_train [--data /tmp/ds_synth --mix 1,1] \
        --val /tmp/ds_dev --ckpt-dir runs/skel --steps 20000

Resumable: `--resume` continues from `<ckpt-dir>/last.pt` (model, optimizer, step, RNG
states). Logs to stdout (line-buffered) and `<ckpt-dir>/log.csv`.
"""

from __future__ import annotations

import argparse
import copy
import csv
import math
import os
import random
import sys
import time

import numpy as np
import torch

from .data import MixedSampler, SkeletonDataset, iterate_eval
from .init_from_onnx import config_of, load_onnx_weights
from .model import PAD, ModelConfig, SkeletonModel, loss_fn, tiny_config


def add_shared_args(ap, batch: int, lr: float, min_lr_ratio: float, threads: int):
    """The data, optimiser, sampling and model-size options both trainers take
    (`train.py` here and `train_fast.py`), with the defaults that differ passed in."""
    ap.add_argument("--data", action="append", required=True, help="dataset dir (repeatable)")
    ap.add_argument("--mix", default=None, help="comma-separated sampling weights, one per --data (default: by size)")
    ap.add_argument("--init-onnx", default=None,
                    help="start a new run from the weights of an exported model folder (its model_config.json sets the size)")
    ap.add_argument("--batch", type=int, default=batch)
    ap.add_argument("--lr", type=float, default=lr)
    ap.add_argument("--min-lr-ratio", type=float, default=min_lr_ratio)
    ap.add_argument("--weight-decay", type=float, default=0.01)
    ap.add_argument("--clip", type=float, default=1.0)
    ap.add_argument("--points-min", type=int, default=512, help="random subset size per step, lower bound")
    ap.add_argument("--points-max", type=int, default=2048, help="random subset size per step, upper bound")
    ap.add_argument("--cls-drop", type=float, default=0.3, help="probability of replacing the class token with <cls:none>")
    ap.add_argument("--bucket-pool", type=int, default=8, help="length bucketing pool, in batches (1 = off)")
    ap.add_argument("--threads", type=int, default=threads, help="CPU threads (0 = torch's default)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--coord-sigma", type=float, default=0.0,
                    help="Gaussian width, in bins, of the training target of coordinate tokens (0 = one-hot)")
    ap.add_argument("--config", choices=["full", "tiny"], default="full")
    ap.add_argument("--d-model", type=int)
    ap.add_argument("--heads", type=int)
    ap.add_argument("--layers", type=int, help="decoder layers")
    ap.add_argument("--latents", type=int)
    ap.add_argument("--d-ff", type=int)
    ap.add_argument("--dropout", type=float)
    ap.add_argument("--max-tokens", type=int, default=512)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_shared_args(ap, batch=32, lr=3e-4, min_lr_ratio=0.1, threads=2)
    ap.add_argument("--val", default=None, help="held-out dataset dir, for monitoring only (e.g. the dev split)")
    ap.add_argument("--ckpt-dir", required=True)
    ap.add_argument("--resume", action="store_true", help="continue from <ckpt-dir>/last.pt if present")
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--warmup", type=int, default=500)
    ap.add_argument("--precision", choices=["auto", "bf16", "fp32"], default="auto",
                    help="bf16 = torch.autocast('cpu', bfloat16). auto: bf16 only where the CPU has native bf16 "
                         "(avx512_bf16 / amx_bf16); elsewhere bf16 matmuls are emulated and ~50-100x slower")
    ap.add_argument("--log-every", type=int, default=10)
    ap.add_argument("--ckpt-every", type=int, default=250)
    ap.add_argument("--val-every", type=int, default=500)
    ap.add_argument("--ema", type=float, default=0.0,
                    help="keep an exponential moving average of the weights with this decay (0 = off); "
                         "snapshots and --val then use the average")
    ap.add_argument("--snapshot-every", type=int, default=0,
                    help="also write weights-only snapshots <ckpt-dir>/weights_<step>.pt this often (0 = off), "
                         "so a later, geometric evaluation can compare steps")
    ap.add_argument("--bench", type=int, default=0, help="only time this many steps (after --bench-warmup steps), then exit")
    ap.add_argument("--bench-warmup", type=int, default=2)
    return ap.parse_args(argv)


def build_config(a) -> ModelConfig:
    cfg = tiny_config() if a.config == "tiny" else ModelConfig()
    for k, attr in [("d_model", "d_model"), ("heads", "n_heads"), ("layers", "dec_layers"), ("latents", "n_latents"),
                    ("d_ff", "d_ff"), ("dropout", "dropout")]:
        v = getattr(a, k)
        if v is not None:
            setattr(cfg, attr, v)
    cfg.max_tokens = a.max_tokens
    return cfg


def cosine_lr(a, prog: float) -> float:
    """From `a.lr` down to `a.min_lr_ratio` of it along half a cosine, `prog` from 0 to 1."""
    prog = min(1.0, prog)
    return a.lr * (a.min_lr_ratio + (1 - a.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * prog)))


def lr_at(step, a):
    if step < a.warmup:
        return a.lr * (step + 1) / a.warmup
    return cosine_lr(a, (step - a.warmup) / max(1, a.steps - a.warmup))


def make_optimizer(model, a):
    decay, no_decay = [], []
    for n, p in model.named_parameters():
        if not p.requires_grad:
            continue
        (decay if p.dim() >= 2 and "tok." not in n and "pos." not in n and "latents" not in n else no_decay).append(p)
    return torch.optim.AdamW([{"params": decay, "weight_decay": a.weight_decay}, {"params": no_decay, "weight_decay": 0.0}],
                             lr=a.lr, betas=(0.9, 0.95))


def cpu_has_native_bf16() -> bool:
    try:
        flags = open("/proc/cpuinfo").read()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


def autocast(a):
    if a.precision == "bf16":
        return torch.autocast("cpu", dtype=torch.bfloat16)
    return torch.autocast("cpu", enabled=False)


@torch.no_grad()
def evaluate(model, ds, a, cls_none=False):
    model.eval()
    tot, cnt = 0.0, 0
    for pts, ids in iterate_eval(ds, batch_size=a.batch, cls_none=cls_none):
        with autocast(a):
            logits = model(pts, ids)
        l, c = loss_fn(logits, ids)
        tot += float(l)
        cnt += int(c)
    model.train()
    return tot / max(1, cnt)


def save_atomic(obj, path):
    tmp = path + ".tmp"
    torch.save(obj, tmp)
    os.replace(tmp, path)


def main(argv=None):
    sys.stdout.reconfigure(line_buffering=True)
    a = parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    if a.precision == "auto":
        a.precision = "bf16" if cpu_has_native_bf16() else "fp32"
        print(f"[train] precision auto -> {a.precision}")
    os.makedirs(a.ckpt_dir, exist_ok=True)
    last_path = os.path.join(a.ckpt_dir, "last.pt")

    resume = None
    if a.resume and os.path.exists(last_path):
        resume = torch.load(last_path, map_location="cpu", weights_only=False)
        cfg = ModelConfig.from_dict(resume["config"])
        print(f"[train] resuming from {last_path} at step {resume['step']}")
    elif a.init_onnx:
        cfg = ModelConfig.from_dict(config_of(a.init_onnx))
    else:
        cfg = build_config(a)

    random.seed(a.seed)
    np.random.seed(a.seed)
    torch.manual_seed(a.seed)

    datasets = [SkeletonDataset(d, max_tokens=cfg.max_tokens) for d in a.data]
    mix = [float(x) for x in a.mix.split(",")] if a.mix else None
    sampler = MixedSampler(datasets, mix, seed=a.seed, pool=a.bucket_pool)
    val = SkeletonDataset(a.val, max_tokens=cfg.max_tokens) if a.val else None
    for d in a.data:
        if "dev" in os.path.basename(os.path.normpath(d)).lower():
            print(f"[train] WARNING: --data {d} looks like the dev split; never train on dev")

    model = SkeletonModel(cfg)
    opt = make_optimizer(model, a)
    ema = None
    step = 0
    best_val = float("inf")
    if resume is not None:
        model.load_state_dict(resume["model"])
        opt.load_state_dict(resume["optimizer"])
        step = resume["step"]
        best_val = resume.get("best_val", best_val)
        sampler.set_state(resume["sampler_rng"])
        torch.set_rng_state(resume["torch_rng"])
        random.setstate(resume["py_rng"])
    elif a.init_onnx:
        load_onnx_weights(model, a.init_onnx)
        print(f"[train] weights from {a.init_onnx}")
    if a.ema > 0:
        # The average starts at the starting weights and is kept in fp32 outside autocast.
        ema = copy.deepcopy(model).eval()
        for p_ in ema.parameters():
            p_.requires_grad_(False)
        if resume is not None and "ema" in resume:
            ema.load_state_dict(resume["ema"])
    n = model.num_params()
    print(f"[train] config {cfg.to_dict()}")
    print(f"[train] params encoder {n['encoder']:,} decoder {n['decoder']:,} total {n['total']:,}")

    log_path = os.path.join(a.ckpt_dir, "log.csv")
    new_log = not (resume is not None and os.path.exists(log_path))
    log_f = open(log_path, "w" if new_log else "a", newline="")
    log = csv.writer(log_f)
    if new_log:
        log.writerow(["step", "loss", "lr", "grad_norm", "tokens_per_s", "steps_per_s", "val_loss", "val_loss_nocls", "elapsed_s"])

    def checkpoint(path):
        save_atomic({
            "config": cfg.to_dict(), "model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
            "best_val": best_val, "sampler_rng": sampler.state(), "torch_rng": torch.get_rng_state(),
            "py_rng": random.getstate(), "args": vars(a),
            **({"ema": ema.state_dict()} if ema is not None else {}),
        }, path)

    def snapshot():
        path = os.path.join(a.ckpt_dir, f"weights_{step:06d}.pt")
        save_atomic({"config": cfg.to_dict(), "model": (ema or model).state_dict(), "step": step,
                     "ema": a.ema}, path)

    model.train()
    t0 = time.time()
    win_t, win_steps, win_tokens, win_loss, win_cnt = time.time(), 0, 0, 0.0, 0
    bench_start = None
    while step < a.steps:
        if a.bench and step == a.bench_warmup and bench_start is None:
            bench_start = time.time()
        lr = lr_at(step, a)
        for g in opt.param_groups:
            g["lr"] = lr
        n_pts = int(sampler.rng.integers(a.points_min, a.points_max + 1))
        pts, ids = sampler.batch(a.batch, n_pts, a.cls_drop)
        with autocast(a):
            logits = model(pts, ids)
        lsum, cnt = loss_fn(logits, ids, coord_sigma=a.coord_sigma)
        loss = lsum / cnt.clamp(min=1)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gn = torch.nn.utils.clip_grad_norm_(model.parameters(), a.clip)
        opt.step()
        if ema is not None:
            with torch.no_grad():
                for e_, p_ in zip(ema.parameters(), model.parameters()):
                    e_.lerp_(p_.detach(), 1.0 - a.ema)
                for e_, b_ in zip(ema.buffers(), model.buffers()):
                    e_.copy_(b_)
        step += 1
        win_steps += 1
        win_tokens += int((ids != PAD).sum())
        win_loss += float(lsum.detach())
        win_cnt += int(cnt)

        if a.bench and step == a.bench_warmup + a.bench:
            dt = time.time() - bench_start
            print(f"[bench] {a.bench} steps in {dt:.1f}s: {a.bench / dt:.3f} steps/s, {dt / a.bench:.2f} s/step "
                  f"(batch {a.batch}, {a.precision}, {a.threads} threads)")
            return

        val_loss = val_nocls = ""
        if val is not None and (step % a.val_every == 0 or step == a.steps):
            val_loss = evaluate(ema or model, val, a)
            val_nocls = evaluate(ema or model, val, a, cls_none=True)
            print(f"[val] step {step} val_loss {val_loss:.4f} val_loss_nocls {val_nocls:.4f}")
            if val_loss < best_val:
                best_val = val_loss
                checkpoint(os.path.join(a.ckpt_dir, "best.pt"))
        if step % a.log_every == 0 or step == a.steps or val_loss != "":
            dt = time.time() - win_t
            row = [step, win_loss / max(1, win_cnt), lr, float(gn), win_tokens / dt, win_steps / dt, val_loss, val_nocls,
                   time.time() - t0]
            print(f"[train] step {step} loss {row[1]:.4f} lr {lr:.2e} gnorm {row[3]:.2f} "
                  f"tok/s {row[4]:.0f} steps/s {row[5]:.3f} elapsed {row[8]:.0f}s")
            log.writerow(row)
            log_f.flush()
            win_t, win_steps, win_tokens, win_loss, win_cnt = time.time(), 0, 0, 0.0, 0
        if step % a.ckpt_every == 0 or step == a.steps:
            checkpoint(last_path)
        if a.snapshot_every and (step % a.snapshot_every == 0 or step == a.steps):
            snapshot()
    log_f.close()
    print(f"[train] done at step {step}; checkpoint {last_path}")


if __name__ == "__main__":
    main()
