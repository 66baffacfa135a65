"""The time-budgeted trainer on CPU: its batches, its schedule and a short run whose
checkpoint `export.py`'s loader reads.

    python -m pytest training/skeleton/test_train_fast.py
"""

from __future__ import annotations

import argparse
import csv
import os
import tempfile

import torch

from . import model as M
from .data import SkeletonDataset
from .test_train import write_fake_dataset
from .train_fast import DeviceData, DeviceSampler, main as fast_main, schedule


def _sets(n_sets=2):
    out = []
    for k in range(n_sets):
        d = write_fake_dataset(tempfile.mkdtemp(prefix="fast_ds_"), n_items=10 + k, seed=k, long_item=False)
        out.append(DeviceData(SkeletonDataset(d, log=lambda *_: None), torch.device("cpu")))
    return out


def test_batches_mix_sets_subset_points_and_drop_classes():
    sets = _sets()
    s = DeviceSampler(sets, [1.0, 0.0], batch=4, pool=3, device=torch.device("cpu"), seed=0)
    originals = {tuple(r) for r in sets[0].points.float().reshape(-1, 6).tolist()}
    for _ in range(6):
        pts, ids = s.next(16, cls_drop=1.0)
        assert pts.shape == (4, 16, 6) and pts.dtype == torch.float32
        # weight 0 on the second set: every row comes from the first, and is one of its samples
        assert all(tuple(r) in originals for r in pts.reshape(-1, 6).tolist())
        assert (ids[:, 0] == M.BOS).all() and (ids[:, 1] == M.CLS_NONE).all()
        # right padding only: after a row's <eos> there is nothing but <pad>
        for row in ids.tolist():
            end = row.index(M.EOS)
            assert all(t == M.PAD for t in row[end + 1:])
        # distinct samples per item (a subset without replacement)
        assert all(len({tuple(r) for r in item.tolist()}) == 16 for item in pts)


def test_schedule_warms_up_decays_and_narrows_targets():
    a = argparse.Namespace(lr=1e-3, min_lr_ratio=0.1, warmup_frac=0.1, coord_sigma=2.0, coord_sigma_end=1.0)
    assert schedule(0.05, a)[0] < schedule(0.1, a)[0] == 1e-3
    assert abs(schedule(1.0, a)[0] - 1e-4) < 1e-12
    assert schedule(0.0, a)[1] == 2.0 and schedule(0.5, a)[1] == 1.5 and schedule(1.0, a)[1] == 1.0
    a.coord_sigma_end = None
    assert schedule(0.7, a)[1] == 2.0


def test_short_run_writes_a_loadable_checkpoint_and_log():
    d1 = write_fake_dataset(tempfile.mkdtemp(prefix="fast_a_"), seed=1, long_item=False)
    d2 = write_fake_dataset(tempfile.mkdtemp(prefix="fast_b_"), seed=2, long_item=False)
    out = tempfile.mkdtemp(prefix="fast_out_")
    fast_main(["--data", d1, "--data", d2, "--mix", "1,1", "--out", out, "--minutes", "5", "--max-steps", "6",
               "--batch", "4", "--config", "tiny", "--device", "cpu", "--precision", "fp32", "--points-min", "16",
               "--points-max", "32", "--log-seconds", "0", "--coord-sigma", "1"])
    model, ck = M.load_model(os.path.join(out, "last.pt"))
    assert ck["step"] == 6 and isinstance(model, M.SkeletonModel)
    rows = list(csv.DictReader(open(os.path.join(out, "log.csv"))))
    assert len(rows) == 6 and all(float(r["loss"]) > 0 for r in rows)


if __name__ == "__main__":
    from training.testing import run_tests

    run_tests(globals())
