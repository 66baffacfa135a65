"""Skin model tests: ONNX export vs PyTorch, the residual start, the loss, the data reader.

    python -m training.skin.test_skin        # or: python -m pytest training/skin -q
"""

from __future__ import annotations

import json
import os
import tempfile

import numpy as np
import torch

from .data import MixedSampler, SkinDataset, collate
from .export import example_inputs, export_onnx, max_diff, to_fp16
from .model import BONE_FEATURES, PAIR_FEATURES, VERT_FEATURES, SkinConfig, SkinModel, loss_fn, sparsify


def _random_model(seed=0):
    torch.manual_seed(seed)
    m = SkinModel(SkinConfig(d=32, heads=4))
    # A trained-like head: the zero init would hide export errors in the correction path.
    with torch.no_grad():
        m.head[2].weight.normal_(0, 0.5)
        m.head[2].bias.normal_(0, 0.5)
    return m.eval()


def test_onnx_matches_pytorch_for_any_row_bone_and_candidate_count():
    torch.set_num_threads(1)
    m = _random_model()
    with tempfile.TemporaryDirectory() as d:
        p = os.path.join(d, "skin.onnx")
        export_onnx(m, p)
        assert max_diff(m, p) < 1e-4
        p16 = os.path.join(d, "skin.fp16.onnx")
        to_fp16(p, p16)
        assert max_diff(m, p16) < 2e-2
        assert os.path.getsize(p16) < os.path.getsize(p)


def test_untrained_model_gives_the_geometric_blend_and_pads_get_nothing():
    m = SkinModel(SkinConfig(d=16, heads=2)).eval()
    vert, bone, cand, pair = example_inputs(rows=20, bones=5, k=6)
    pair[cand < 0, 2] = 0.0
    pair[..., 2] = pair[..., 2] / pair[..., 2].sum(-1, keepdim=True)
    with torch.no_grad():
        w = m(vert, bone, cand, pair)
    assert torch.allclose(w.sum(-1), torch.ones(20), atol=1e-5)
    assert float(w[cand < 0].abs().max()) < 1e-6
    assert torch.allclose(w, pair[..., 2], atol=2e-3)


def test_without_name_hints_the_names_do_not_matter():
    vert, bone, cand, pair = example_inputs(rows=30, bones=7, k=5)
    renamed = bone.clone()
    renamed[:, 12:15] = 1.0 - renamed[:, 12:15]
    blind, seeing = _random_model(1), _random_model(1)
    blind.cfg.name_hints = False
    with torch.no_grad():
        assert float((blind(vert, bone, cand, pair) - blind(vert, renamed, cand, pair)).abs().max()) == 0.0
        assert float((seeing(vert, bone, cand, pair) - seeing(vert, renamed, cand, pair)).abs().max()) > 1e-4


def test_sparsify_keeps_the_rust_rules():
    w = torch.tensor([[0.5, 0.3, 0.12, 0.04, 0.04], [0.9, 0.02, 0.02, 0.03, 0.03]])
    cand = torch.tensor([[0, 1, 2, 3, 4], [0, 1, 2, 3, -1]])
    s = sparsify(w, cand, max_influences=4, min_weight=0.05)
    assert torch.allclose(s.sum(-1), torch.ones(2))
    assert int((s[0] > 0).sum()) == 3 and float(s[0, 4]) == 0.0
    assert torch.allclose(s[1], torch.tensor([1.0, 0, 0, 0, 0]))


def test_training_steps_lower_the_loss():
    torch.manual_seed(0)
    m = SkinModel(SkinConfig(d=32, heads=4))
    vert, bone, cand, pair = example_inputs(rows=64, bones=6, k=5, seed=3)
    # Artists weight only the second candidate: geometry alone gets this wrong.
    target = torch.zeros(64, 5)
    target[:, 1] = 1.0
    key = cand[:, 1]
    opt = torch.optim.Adam(m.parameters(), lr=3e-3)
    first = None
    for _ in range(60):
        loss = loss_fn(m.logits(vert, bone, cand, pair), target, key)
        first = float(loss.detach()) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.5 * first, (first, float(loss.detach()))


def _write_dataset(root, items):
    """The layout of src/dataset/skin.rs, from (rows, bones, k) per item."""
    rng = np.random.default_rng(0)
    rows_all = sum(r for r, _, _ in items)
    k = items[0][2]
    index, ro, bo = [], 0, 0
    cands = []
    for r, b, _ in items:
        c = rng.integers(0, b, size=(r, k)).astype("<i4")
        c[0, -1] = -1
        cands.append(c)
        index.append({"file": f"f{len(index)}.glb", "category": "x", "aug": 0, "row_offset": ro, "rows": r,
                      "bone_offset": bo, "bones": b, "k": k, "vertices": r})
        ro, bo = ro + r, bo + b
    np.concatenate(cands).tofile(os.path.join(root, "cand.i32"))
    rng.random((rows_all, VERT_FEATURES), dtype=np.float32).tofile(os.path.join(root, "vert.f32"))
    rng.random((rows_all, k, PAIR_FEATURES), dtype=np.float32).tofile(os.path.join(root, "pair.f32"))
    t = rng.random((rows_all, k), dtype=np.float32)
    (t / t.sum(-1, keepdims=True)).tofile(os.path.join(root, "target.f32"))
    rng.random((bo, BONE_FEATURES), dtype=np.float32).tofile(os.path.join(root, "bone.f32"))
    with open(os.path.join(root, "index.jsonl"), "w") as f:
        for it in index:
            f.write(json.dumps(it) + "\n")


def test_batches_shift_candidates_into_the_stacked_bone_table():
    with tempfile.TemporaryDirectory() as d:
        _write_dataset(d, [(10, 3, 4), (7, 5, 4)])
        ds = SkinDataset(d, log=lambda *_: None)
        b = collate([(ds, 1, ds.rows_of(1, None, 100)), (ds, 0, ds.rows_of(0, None, 100))])
        assert b["bone"].shape == (8, BONE_FEATURES)
        # Item 1 comes first here: its bones are 0..5, item 0's are 5..8.
        c = b["cand"]
        assert int(c[:7].max()) < 5 and int(c[7:][c[7:] >= 0].min()) >= 5
        assert bool((c[7] == -1).any()) and bool((c[0] == -1).any())
        assert b["bone_item"].tolist() == [0] * 5 + [1] * 3
        s = MixedSampler([ds], None, seed=0).batch(items=3, rows=4)
        assert s["vert"].shape[0] <= 12 and s["pair"].shape[1:] == (4, PAIR_FEATURES)
        with open(os.path.join(d, "vert.f32"), "ab") as f:
            f.write(b"\0" * 4)
        try:
            SkinDataset(d, log=lambda *_: None)
            raise AssertionError("a truncated or padded array must be refused")
        except ValueError:
            pass


if __name__ == "__main__":
    from ..testing import run_tests

    run_tests(globals())
