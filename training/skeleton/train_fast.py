"""Trains the skeleton model with every data set held in the device's memory, for a fixed
wall-clock budget: the trainer for a lent GPU, where the numpy collate of `train.py` would
starve the device. The same model, loss and data sets as `train.py`; it also runs on CPU
(that is how its test runs).

    python -m training.skeleton.train_fast --data ds_real --data ds_syn --mix 1,1 \
        --out run --minutes 6 --batch 256 --lr 6e-4 --coord-sigma 2 --coord-sigma-end 1

Differences from `train.py`, each because the budget is time, not steps:
- the learning rate (warmup, then cosine) and the coordinate target width (linear from
  `--coord-sigma` to `--coord-sigma-end`) follow elapsed time over `--minutes`, so the run
  ends annealed however fast the device turns out to be;
- weights-only checkpoints (`{config, model, step}`, what `export.py` reads) are written
  every `--ckpt-seconds` and at the end; there is no resume.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import torch

from .data import SkeletonDataset
from .init_from_onnx import config_of, load_onnx_weights
from .model import CLS_BASE, CLS_NONE, PAD, VOCAB_SIZE, ModelConfig, SkeletonModel, loss_fn
from .train import add_shared_args, build_config, cosine_lr, cpu_has_native_bf16, make_optimizer, save_atomic


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_shared_args(ap, batch=256, lr=6e-4, min_lr_ratio=0.05, threads=0)
    ap.add_argument("--out", required=True, help="folder for last.pt and log.csv")
    ap.add_argument("--minutes", type=float, required=True, help="wall-clock budget of the optimisation loop")
    ap.add_argument("--max-steps", type=int, default=0, help="stop after this many steps too (0 = time only)")
    ap.add_argument("--warmup-frac", type=float, default=0.05)
    ap.add_argument("--coord-sigma-end", type=float, default=None,
                    help="target width at the end of the budget (default: --coord-sigma throughout)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--precision", choices=["auto", "bf16", "fp32"], default="auto",
                    help="bf16 autocast: auto = on CUDA, or on a CPU with native bf16")
    ap.add_argument("--ckpt-seconds", type=float, default=60.0)
    ap.add_argument("--log-seconds", type=float, default=15.0)
    return ap.parse_args(argv)


class DeviceData:
    """One data set on the device: points (N, P, 6) in fp16, tokens right-padded (N, T)."""

    def __init__(self, ds: SkeletonDataset, device):
        rows = ds.keep
        self.n = len(rows)
        self.points = torch.from_numpy(np.ascontiguousarray(ds.points[rows])).to(device=device, dtype=torch.float16)
        lens = [len(ds.items[i].tokens) for i in rows]
        ids = np.full((self.n, max(lens)), PAD, dtype=np.int64)
        for j, i in enumerate(rows):
            ids[j, : lens[j]] = ds.items[i].tokens
        self.ids = torch.from_numpy(ids).to(device)
        self.lens = torch.tensor(lens, device=device)


class DeviceSampler:
    """Mixed, length-bucketed batches drawn on the device (`data.MixedSampler`'s scheme)."""

    def __init__(self, sets, weights, batch, pool, device, seed):
        self.sets, self.batch, self.pool, self.device = sets, batch, max(1, pool), device
        w = torch.tensor(weights if weights else [s.n for s in sets], dtype=torch.float64)
        self.w = (w / w.sum()).float().to(device)
        self.gen = torch.Generator(device=device)
        self.gen.manual_seed(seed)
        self.queue = []
        self.n_points = min(s.points.shape[1] for s in sets)
        # One token width for every set, so a batch mixing them slices instead of padding.
        width = max(s.ids.shape[1] for s in sets)
        for s in sets:
            if s.ids.shape[1] < width:
                s.ids = torch.nn.functional.pad(s.ids, (0, width - s.ids.shape[1]), value=PAD)

    def _refill(self):
        n = self.batch * self.pool
        which = torch.multinomial(self.w, n, replacement=True, generator=self.gen)
        picks = []
        for k, s in enumerate(self.sets):
            m = int((which == k).sum())
            if m:
                idx = torch.randint(s.n, (m,), device=self.device, generator=self.gen)
                picks.append((torch.full((m,), k, device=self.device), idx, s.lens[idx]))
        ds_of = torch.cat([p[0] for p in picks])
        idx = torch.cat([p[1] for p in picks])
        lens, order = torch.sort(torch.cat([p[2] for p in picks]))
        ds_of, idx = ds_of[order], idx[order]
        # Sorted by length, so a batch's longest item is its last: read once per refill.
        longest = torch.stack([c[-1] for c in lens.split(self.batch)]).tolist()
        chunks = list(zip(ds_of.split(self.batch), idx.split(self.batch), longest))
        perm = torch.randperm(len(chunks), generator=self.gen, device=self.device).tolist()
        self.queue = [chunks[i] for i in perm]

    def next(self, n_points: int, cls_drop: float):
        if not self.queue:
            self._refill()
        ds_of, idx, t = self.queue.pop()
        pts = torch.empty((len(idx), self.n_points, 6), device=self.device, dtype=torch.float16)
        ids = torch.empty((len(idx), t), device=self.device, dtype=torch.long)
        for k in ds_of.unique().tolist():
            sel = (ds_of == k).nonzero().squeeze(1)
            s = self.sets[k]
            pts[sel] = s.points[idx[sel]]
            ids[sel] = s.ids[idx[sel], :t]
        n_points = min(n_points, self.n_points)
        if n_points < self.n_points:
            # A random subset without replacement per item, in surface-sample order.
            keys = torch.rand((len(idx), self.n_points), device=self.device, generator=self.gen)
            sub = torch.sort(keys.topk(n_points, dim=1).indices, dim=1).values
            pts = torch.gather(pts, 1, sub.unsqueeze(-1).expand(-1, -1, 6))
        if cls_drop > 0 and t > 1:
            is_cls = (ids[:, 1] >= CLS_BASE) & (ids[:, 1] < VOCAB_SIZE)
            drop = torch.rand(len(idx), device=self.device, generator=self.gen) < cls_drop
            ids[:, 1] = torch.where(is_cls & drop, torch.full_like(ids[:, 1], CLS_NONE), ids[:, 1])
        return pts.float(), ids


def schedule(frac: float, a) -> tuple[float, float]:
    """Learning rate and coordinate-target width at this fraction of the budget."""
    if frac < a.warmup_frac:
        lr = a.lr * max(frac / a.warmup_frac, 1e-3)
    else:
        lr = cosine_lr(a, (frac - a.warmup_frac) / max(1e-9, 1 - a.warmup_frac))
    end = a.coord_sigma if a.coord_sigma_end is None else a.coord_sigma_end
    return lr, a.coord_sigma + (end - a.coord_sigma) * min(1.0, frac)


def main(argv=None):
    sys.stdout.reconfigure(line_buffering=True)
    a = parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    dev = torch.device(a.device)
    cfg = ModelConfig.from_dict(config_of(a.init_onnx)) if a.init_onnx else build_config(a)
    sets = [DeviceData(SkeletonDataset(d, max_tokens=cfg.max_tokens), dev) for d in a.data]
    mix = [float(x) for x in a.mix.split(",")] if a.mix else None
    sampler = DeviceSampler(sets, mix, a.batch, a.bucket_pool, dev, a.seed)
    model = SkeletonModel(cfg)
    if a.init_onnx:
        load_onnx_weights(model, a.init_onnx)
    model.to(dev).train()
    opt = make_optimizer(model, a)
    use_bf16 = a.precision == "bf16" or (a.precision == "auto" and (dev.type == "cuda" or cpu_has_native_bf16()))
    print(f"[fast] device {dev} bf16 {use_bf16} params {model.num_params()['total']:,} "
          f"items {[s.n for s in sets]} batch {a.batch} budget {a.minutes} min")
    os.makedirs(a.out, exist_ok=True)
    log = open(os.path.join(a.out, "log.csv"), "w")
    log.write("step,elapsed_s,loss,lr,coord_sigma,grad_norm,items_per_s\n")

    def save(step):
        state = {k: v.detach().float().cpu() for k, v in model.state_dict().items()}
        save_atomic({"config": cfg.to_dict(), "model": state, "step": step, "args": vars(a)},
                    os.path.join(a.out, "last.pt"))

    rng = np.random.default_rng(a.seed)
    budget = a.minutes * 60.0
    t0 = last_ckpt = last_log = time.time()
    # Loss sums stay on the device between log lines: reading them every step would make
    # each step wait for the device.
    step, win_items = 0, 0
    win_loss = torch.zeros((), device=dev)
    win_cnt = torch.zeros((), device=dev, dtype=torch.long)
    while True:
        frac = (time.time() - t0) / budget
        if frac >= 1.0 or (a.max_steps and step >= a.max_steps):
            break
        lr, sigma = schedule(frac, a)
        for g in opt.param_groups:
            g["lr"] = lr
        pts, ids = sampler.next(int(rng.integers(a.points_min, a.points_max + 1)), a.cls_drop)
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=use_bf16):
            logits = model(pts, ids)
        lsum, cnt = loss_fn(logits, ids, coord_sigma=sigma)
        loss = lsum / cnt.clamp(min=1)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gn = torch.nn.utils.clip_grad_norm_(model.parameters(), a.clip)
        opt.step()
        step += 1
        win_items += len(ids)
        win_loss += lsum.detach().float()
        win_cnt += cnt
        now = time.time()
        if now - last_log >= a.log_seconds:
            line = (f"{step},{now - t0:.0f},{float(win_loss) / max(1, int(win_cnt)):.4f},{lr:.2e},{sigma:.2f},"
                    f"{float(gn):.2f},{win_items / (now - last_log):.0f}")
            print("[fast]", line)
            log.write(line + "\n")
            log.flush()
            last_log, win_items = now, 0
            win_loss.zero_()
            win_cnt.zero_()
        if now - last_ckpt >= a.ckpt_seconds:
            save(step)
            last_ckpt = now
    save(step)
    print(f"[fast] done: {step} steps in {time.time() - t0:.0f}s -> {os.path.join(a.out, 'last.pt')}")


if __name__ == "__main__":
    main()
