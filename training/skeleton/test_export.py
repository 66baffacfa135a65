"""Export contract tests on a tiny random model (d=64, 2 layers); under a minute on 2 cores.

    python -m pytest training/skeleton/test_export.py     # or, without pytest:
    python -m training.skeleton.test_export
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import torch

from . import model as M
from .check_export import OnnxSkeleton, check, greedy_cached, left_pad
from .export import export_all

_CACHE = {}


def _exported():
    """Exports the tiny model once per process (fp32 + fp16 + int8)."""
    if "dir" not in _CACHE:
        torch.manual_seed(0)
        torch.set_num_threads(2)
        model = M.SkeletonModel(M.tiny_config(d_model=64, dec_layers=2)).eval()
        d = tempfile.mkdtemp(prefix="skel_onnx_")
        _CACHE["info"] = export_all(model, d, log=lambda *_: None)
        _CACHE["dir"], _CACHE["model"] = d, model
    return _CACHE["model"], _CACHE["dir"]


def test_cached_path_matches_training_path():
    torch.manual_seed(1)
    model = M.SkeletonModel(M.tiny_config()).eval()
    pts = torch.randn(2, 100, 6)
    ids = torch.tensor([[M.BOS, M.CLS_NONE, 10, 20, 30, M.EOS], [M.BOS, M.CLS_BASE + 1, 5, 6, 7, 8]])
    with torch.no_grad():
        ref = model(pts, ids)
        prefix = model.encoder(pts)
        L = prefix.shape[1]
        past = [(torch.zeros(2, 4, 0, 16), torch.zeros(2, 4, 0, 16)) for _ in model.decoder.layers]
        pos = torch.arange(L + 3).repeat(2, 1)
        mask = torch.ones(2, L + 3, dtype=torch.int64)
        lg, new = model.decoder.forward_cached(ids[:, :3], prefix, pos, mask, past)
        past = M.append_past(past, new)
        outs = [lg]
        for t in range(3, 6):
            mask = torch.ones(2, L + t + 1, dtype=torch.int64)
            lg, new = model.decoder.forward_cached(ids[:, t:t + 1], prefix[:, :0], torch.full((2, 1), L + t), mask, past)
            past = M.append_past(past, new)
            outs.append(lg)
    assert torch.allclose(torch.cat(outs, 1), ref, atol=1e-5)


def test_encoder_is_permutation_invariant():
    torch.manual_seed(2)
    model = M.SkeletonModel(M.tiny_config()).eval()
    pts = torch.randn(1, 300, 6)
    with torch.no_grad():
        a = model.encoder(pts)
        b = model.encoder(pts[:, torch.randperm(300)])
    assert torch.allclose(a, b, atol=1e-5)


def test_export_contract_io():
    model, d = _exported()
    m = OnnxSkeleton(os.path.join(d, "encoder.onnx"), os.path.join(d, "decoder.onnx"))
    cfg = model.cfg
    assert [i.name for i in m.enc.get_inputs()] == ["points"]
    assert [o.name for o in m.enc.get_outputs()] == ["prefix"]
    names = [i.name for i in m.dec.get_inputs()]
    assert names[:4] == ["input_ids", "prefix", "position_ids", "attention_mask"]
    assert names[4:] == [f"past_key_values.{i}.{kv}" for i in range(cfg.dec_layers) for kv in ("key", "value")]
    outs = [o.name for o in m.dec.get_outputs()]
    assert outs == ["logits"] + [f"new_key_values.{i}.{kv}" for i in range(cfg.dec_layers) for kv in ("key", "value")]
    assert meta_contract(m) == "skeleton-v2"
    meta = m.dec.get_modelmeta().custom_metadata_map
    assert int(meta["n_latents"]) == cfg.n_latents and int(meta["vocab_size"]) == M.VOCAB_SIZE
    # shapes: batch 3, 50 points; prefill with 2 tokens then a decode step
    pts = np.random.default_rng(0).normal(size=(3, 50, 6)).astype(np.float32)
    prefix = m.encode(pts)
    assert prefix.shape == (3, cfg.n_latents, cfg.d_model)
    ids, pos, mask = left_pad([[M.BOS, M.CLS_NONE]] * 3, cfg.n_latents)
    logits, new = m.run_decoder(ids, prefix, pos, mask, m.empty_past(3))
    assert logits.shape == (3, 2, M.VOCAB_SIZE)
    assert new[0].shape == (3, cfg.n_heads, cfg.n_latents + 2, cfg.head_dim)
    mask = np.concatenate([mask, np.ones((3, 1), np.int64)], 1)
    logits, new = m.run_decoder(np.full((3, 1), 7), prefix[:, :0], np.full((3, 1), cfg.n_latents + 2), mask, new)
    assert logits.shape == (3, 1, M.VOCAB_SIZE)
    assert new[-1].shape == (3, cfg.n_heads, 1, cfg.head_dim)  # only the new position
    assert np.isfinite(logits).all()


def meta_contract(m):
    return m.dec.get_modelmeta().custom_metadata_map["rigserve.contract"]


def test_unwritten_capacity_is_invisible():
    """A past longer than what was written, its extra slots masked 0 and filled with
    garbage, gives the same logits: the server passes a preallocated buffer that way."""
    model, d = _exported()
    m = OnnxSkeleton(os.path.join(d, "encoder.onnx"), os.path.join(d, "decoder.onnx"))
    cfg = model.cfg
    pts = np.random.default_rng(4).normal(size=(2, 64, 6)).astype(np.float32)
    prefix = m.encode(pts)
    ids, pos, mask = left_pad([[M.BOS, M.CLS_NONE], [M.BOS, M.CLS_BASE + 1]], cfg.n_latents)
    _, new = m.run_decoder(ids, prefix, pos, mask, m.empty_past(2))
    step = (np.full((2, 1), 9), prefix[:, :0], np.full((2, 1), cfg.n_latents + 2))
    ref, _ = m.run_decoder(*step, np.concatenate([mask, np.ones((2, 1), np.int64)], 1), new)
    extra = 5
    junk = [np.concatenate([n, np.random.default_rng(i).normal(size=n.shape[:2] + (extra, n.shape[3])).astype(np.float32) * 50], 2)
            for i, n in enumerate(new)]
    big_mask = np.concatenate([mask, np.zeros((2, extra), np.int64), np.ones((2, 1), np.int64)], 1)
    got, _ = m.run_decoder(*step, big_mask, junk)
    assert np.abs(got - ref).max() < 1e-5


def test_step_flavours_differ_only_in_attention():
    """The exported step uses rigserve's attention op; its GroupQueryAttention twin (what
    stock onnxruntime runs) has the same weights and nodes, and converting back and forth
    gives that twin; a changed weight is caught."""
    import shutil

    import onnx
    from onnx import numpy_helper

    from .step_graph import STEP_FILE, attention_of, build, cache_of, convert, same_but_attention

    model, d = _exported()
    shipped = os.path.join(d, STEP_FILE)
    assert attention_of(shipped) == "rigserve"
    assert cache_of(shipped) == "float16"
    tmp = tempfile.mkdtemp(prefix="skel_step_")
    twin = build(model, os.path.join(tmp, "gqa.onnx"), attention="gqa")
    assert cache_of(twin) == "float32"
    same_but_attention(shipped, twin)
    wide = shutil.copy(shipped, os.path.join(tmp, "wide.onnx"))
    convert(wide, "rigserve", "float32")
    assert (attention_of(wide), cache_of(wide)) == ("rigserve", "float32")
    same_but_attention(wide, shipped)
    try:
        convert(wide, "gqa", "float16")
    except ValueError:
        pass
    else:
        raise AssertionError("GroupQueryAttention was given a float16 cache")
    back = shutil.copy(shipped, os.path.join(tmp, "back.onnx"))
    convert(back, "gqa")
    assert (attention_of(back), cache_of(back)) == ("gqa", "float32")
    same_but_attention(back, twin)
    m = onnx.load(back)
    for t in m.graph.initializer:
        if t.name == "head.w":
            t.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(t) * 1.01, t.name))
    onnx.save(m, back)
    try:
        same_but_attention(back, twin)
    except AssertionError:
        pass
    else:
        raise AssertionError("a changed weight went unnoticed")


def test_export_matches_torch_and_cache():
    model, d = _exported()
    res = check(model, d, steps=10, n_points=256)
    assert res["encoder_max_abs_diff"] <= 1e-4, res
    assert res["cache_vs_recompute_same_tokens"], res
    assert res["cache_vs_recompute_max_logit_diff"] <= 1e-3, res
    assert res["cache_vs_torch_max_logit_diff"] <= 1e-3, res
    assert res["torch_greedy_agrees"], res
    assert res["ok"]
    for v in ("fp16", "int8"):
        assert v in res and np.isfinite(res[v]["logits_max_abs_diff"]), res


def test_left_padding_does_not_change_results():
    """An item decoded alone equals the same item decoded left-padded next to a longer one."""
    model, d = _exported()
    m = OnnxSkeleton(os.path.join(d, "encoder.onnx"), os.path.join(d, "decoder.onnx"))
    pts = np.random.default_rng(3).normal(size=(2, 128, 6)).astype(np.float32)
    prefix = m.encode(pts)
    short, long = [M.BOS, M.CLS_NONE], [M.BOS, M.CLS_BASE + 2, 100, 101, 102, M.BRANCH]
    t_batch, l_batch = greedy_cached(m, prefix, [short, long], 6)
    t_alone, l_alone = greedy_cached(m, prefix[:1], [short], 6)
    assert (t_batch[0] == t_alone[0]).all()
    assert np.abs(l_batch[0] - l_alone[0]).max() < 1e-4


def test_quantized_files_are_smaller():
    _, d = _exported()
    for n in ("encoder", "decoder"):
        base = os.path.getsize(os.path.join(d, f"{n}.onnx"))
        assert os.path.getsize(os.path.join(d, f"{n}.fp16.onnx")) < base
        assert os.path.getsize(os.path.join(d, f"{n}.int8.onnx")) < base


if __name__ == "__main__":
    from training.testing import run_tests

    run_tests(globals())
