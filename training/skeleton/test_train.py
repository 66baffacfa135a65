"""Data loading, loss masking and a resumable tiny training run on a fake data set.

    python -m pytest training/skeleton/test_train.py     # or: python -m training.skeleton.test_train
"""

from __future__ import annotations

import csv
import json
import os
import tempfile

import numpy as np
import torch

from . import model as M
from .data import MixedSampler, SkeletonDataset, collate
from .train import main as train_main


def write_fake_dataset(root: str, n_items: int = 12, n_points: int = 64, seed: int = 0, long_item: bool = True):
    """The `rigserve dataset` layout: points.f32 (items x points x 6) + index.jsonl."""
    rng = np.random.default_rng(seed)
    os.makedirs(root, exist_ok=True)
    pts = rng.uniform(-1, 1, (n_items, n_points, 6)).astype("<f4")
    pts.tofile(os.path.join(root, "points.f32"))
    with open(os.path.join(root, "index.jsonl"), "w") as f:
        for i in range(n_items):
            n_j = 2 + i % 5
            body = rng.integers(0, 256, 3 * n_j).tolist()
            if long_item and i == n_items - 1:
                body = rng.integers(0, 256, 600).tolist()
            toks = [M.BOS, M.CLS_BASE + 1 + i % 8] + body + [M.EOS]
            f.write(json.dumps({"file": f"f{i}.glb", "category": M.CATEGORIES[1 + i % 8], "aug": 0, "bones": n_j,
                                "template": None, "tokens": toks, "normalization": {}}) + "\n")
    return root


def test_dataset_reads_and_drops_long_items():
    d = write_fake_dataset(tempfile.mkdtemp(prefix="skel_ds_"))
    ds = SkeletonDataset(d, max_tokens=512, log=lambda *_: None)
    assert ds.n_points == 64 and len(ds) == 11 and ds.dropped == 1
    p, t = ds.get(0)
    assert p.shape == (64, 6) and t[0] == M.BOS and t[-1] == M.EOS


def test_collate_subsets_and_pads():
    rng = np.random.default_rng(0)
    pts = [np.arange(20 * 6, dtype=np.float32).reshape(20, 6)] * 2
    toks = [np.array([M.BOS, M.CLS_BASE + 3, 1, 2, 3, M.EOS]), np.array([M.BOS, M.CLS_BASE + 1, M.EOS])]
    p, ids = collate(pts, toks, 8, rng, cls_drop=1.0)
    assert p.shape == (2, 8, 6) and ids.shape == (2, 6)
    assert (ids[:, 1] == M.CLS_NONE).all() and (ids[1, 3:] == M.PAD).all()
    # the subset is made of distinct original rows
    assert len({tuple(r) for r in p[0].numpy()}) == 8


def test_loss_ignores_padding_and_class_target():
    ids = torch.tensor([[M.BOS, M.CLS_BASE, 5, M.EOS, M.PAD]])
    logits = torch.zeros(1, 5, M.VOCAB_SIZE)
    _, cnt = M.loss_fn(logits, ids)
    assert int(cnt) == 2  # targets 5 and <eos>


def test_smoothed_coordinate_loss_ranks_near_misses_above_far_ones():
    ids = torch.tensor([[M.BOS, M.CLS_BASE, 100, M.EOS]])

    def peaked_at(tok):
        lg = torch.zeros(1, 4, M.VOCAB_SIZE)
        lg[0, 1, tok] = 8.0  # predicts the coordinate
        lg[0, 2, M.EOS] = 8.0
        return lg

    right, near, far = (float(M.loss_fn(peaked_at(t), ids, coord_sigma=2.0)[0]) for t in (100, 101, 180))
    assert right < near < far
    # One-hot cross-entropy cannot tell a near miss from a far one.
    near1, far1 = (float(M.loss_fn(peaked_at(t), ids)[0]) for t in (101, 180))
    assert abs(near1 - far1) < 1e-4
    # Special tokens keep their one-hot target: only the coordinate term changes.
    lg = peaked_at(100)
    plain, _ = M.loss_fn(lg, ids)
    smooth, cnt = M.loss_fn(lg, ids, coord_sigma=1e-3)
    assert int(cnt) == 2 and abs(float(plain) - float(smooth)) < 1e-4


def test_bucketed_sampler_batches_have_similar_lengths():
    d = write_fake_dataset(tempfile.mkdtemp(prefix="skel_ds_"), n_items=40, long_item=False)
    ds = SkeletonDataset(d, log=lambda *_: None)
    s = MixedSampler([ds], None, seed=0, pool=4)
    st = s.state()
    a = [s.batch(4, 32, 0.0)[1] for _ in range(6)]
    s.set_state(st)
    b = [s.batch(4, 32, 0.0)[1] for _ in range(6)]
    assert all(torch.equal(x, y) for x, y in zip(a, b))  # state restores exactly


def test_tiny_training_runs_and_resumes():
    torch.manual_seed(0)
    root = tempfile.mkdtemp(prefix="skel_train_")
    d = write_fake_dataset(os.path.join(root, "ds"))
    v = write_fake_dataset(os.path.join(root, "val"), n_items=4, seed=1)
    ck = os.path.join(root, "ck")
    common = ["--data", d, "--val", v, "--ckpt-dir", ck, "--config", "tiny", "--batch", "4", "--points-min", "16",
              "--points-max", "32", "--warmup", "2", "--log-every", "2", "--val-every", "3", "--ckpt-every", "3",
              "--precision", "fp32"]
    train_main(common + ["--steps", "6"])
    assert os.path.exists(os.path.join(ck, "last.pt")) and os.path.exists(os.path.join(ck, "best.pt"))
    assert torch.load(os.path.join(ck, "last.pt"), weights_only=False)["step"] == 6
    train_main(common + ["--steps", "8", "--resume"])
    assert torch.load(os.path.join(ck, "last.pt"), weights_only=False)["step"] == 8
    rows = list(csv.DictReader(open(os.path.join(ck, "log.csv"))))
    assert [int(r["step"]) for r in rows if r["step"]][-1] == 8
    assert all(np.isfinite(float(r["loss"])) for r in rows)


def test_ema_snapshots_average_the_weights():
    torch.manual_seed(0)
    root = tempfile.mkdtemp(prefix="skel_ema_")
    d = write_fake_dataset(os.path.join(root, "ds"))
    ck = os.path.join(root, "ck")
    args = ["--data", d, "--ckpt-dir", ck, "--config", "tiny", "--batch", "4", "--points-min", "16",
            "--points-max", "32", "--warmup", "2", "--log-every", "2", "--ckpt-every", "2", "--precision", "fp32",
            "--lr", "1e-2"]
    train_main(args + ["--steps", "4", "--ema", "0.5", "--snapshot-every", "2"])
    assert sorted(f for f in os.listdir(ck) if f.startswith("weights_")) == ["weights_000002.pt", "weights_000004.pt"]
    last = torch.load(os.path.join(ck, "last.pt"), weights_only=False)
    snap = torch.load(os.path.join(ck, "weights_000004.pt"), weights_only=False)
    assert snap["step"] == 4 and snap["ema"] == 0.5
    # The snapshot holds the average, which lags the raw weights but is not the start.
    assert all(torch.equal(snap["model"][k], last["ema"][k]) for k in last["ema"])
    differs = [k for k, v in last["model"].items() if v.is_floating_point() and not torch.equal(v, last["ema"][k])]
    assert differs, "the average equals the raw weights"
    # Resuming keeps the average.
    train_main(args + ["--steps", "5", "--ema", "0.5", "--resume"])
    again = torch.load(os.path.join(ck, "last.pt"), weights_only=False)
    k = differs[0]
    expect = 0.5 * last["ema"][k] + 0.5 * again["model"][k]
    assert torch.allclose(again["ema"][k], expect, atol=1e-6)


if __name__ == "__main__":
    from training.testing import run_tests

    run_tests(globals())
