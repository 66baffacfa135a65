"""Exports a trained skeleton checkpoint to ONNX (see ONNX_CONTRACT.md).

    python -m training.skeleton.export --ckpt runs/skel/last.pt --out models/skeleton

writes `encoder.onnx`, `decoder.onnx` (fp32), `*.fp16.onnx`, `*.int8.onnx` and
`model_config.json` into `--out`.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import warnings
from typing import List

import torch
import torch.nn as nn

from . import model as M
from .model import ModelConfig, SkeletonModel

OPSET = 18
# v2: the decoder returns only the new positions' keys and values (v1 returned the whole
# concatenated cache, a copy of it every step).
CONTRACT = "skeleton-v2"


class EncoderExport(nn.Module):
    def __init__(self, model: SkeletonModel):
        super().__init__()
        self.encoder = model.encoder

    def forward(self, points):
        return self.encoder(points)


class DecoderExport(nn.Module):
    """Flat-signature wrapper: (input_ids, prefix, position_ids, attention_mask, past...) ->
    (logits, new...), past/new ordered layer 0 key, layer 0 value, layer 1 key, ..."""

    def __init__(self, model: SkeletonModel):
        super().__init__()
        self.decoder = model.decoder
        self.n_layers = len(model.decoder.layers)

    def forward(self, input_ids, prefix, position_ids, attention_mask, past_key_values: List[torch.Tensor]):
        past = [(past_key_values[2 * i], past_key_values[2 * i + 1]) for i in range(self.n_layers)]
        logits, presents = self.decoder.forward_cached(input_ids, prefix, position_ids, attention_mask, past)
        out = [logits]
        for k, v in presents:
            out += [k, v]
        return tuple(out)


def decoder_io_names(n_layers: int):
    inputs = ["input_ids", "prefix", "position_ids", "attention_mask"]
    outputs = ["logits"]
    for i in range(n_layers):
        inputs += [f"past_key_values.{i}.key", f"past_key_values.{i}.value"]
        outputs += [f"new_key_values.{i}.key", f"new_key_values.{i}.value"]
    return inputs, outputs


def example_decoder_inputs(cfg: ModelConfig, b=2, t=3, p=5, past=4):
    ids = torch.randint(0, cfg.vocab_size, (b, t), dtype=torch.int64)
    prefix = torch.randn(b, p, cfg.d_model)
    pos = torch.arange(past, past + p + t, dtype=torch.int64).unsqueeze(0).repeat(b, 1)
    mask = torch.ones(b, past + p + t, dtype=torch.int64)
    pkv = [torch.randn(b, cfg.n_heads, past, cfg.head_dim) for _ in range(2 * cfg.dec_layers)]
    return ids, prefix, pos, mask, pkv


def _metadata(cfg: ModelConfig, part: str) -> dict:
    return {
        "rigserve.part": part,
        "rigserve.contract": CONTRACT,
        "rigserve.config": json.dumps(cfg.to_dict()),
        "d_model": str(cfg.d_model),
        "n_latents": str(cfg.n_latents),
        "n_layers": str(cfg.dec_layers),
        "n_heads": str(cfg.n_heads),
        "head_dim": str(cfg.head_dim),
        "vocab_size": str(cfg.vocab_size),
        "max_positions": str(cfg.max_positions),
        "max_tokens": str(cfg.max_tokens),
    }


def _rename_dims(path: str, names: dict):
    """Gives the dynamic dimensions readable names. `names` maps an input/output name to one
    name (or None to keep) per dimension. Symbols of the dynamo exporter (s12, "s1 + s2")
    are replaced everywhere they occur, including intermediate value_info."""
    import re

    import onnx

    m = onnx.load(path)
    sym = {}
    for vi in list(m.graph.input) + list(m.graph.output):
        want = names.get(vi.name)
        if not want:
            continue
        for d, n in zip(vi.type.tensor_type.shape.dim, want):
            if n is not None and d.dim_param:
                sym.setdefault(d.dim_param, n)
                d.dim_param = n
    single = {k: v for k, v in sym.items() if re.fullmatch(r"s\d+", k)}
    for vi in m.graph.value_info:
        for d in vi.type.tensor_type.shape.dim:
            if d.dim_param in sym:
                d.dim_param = sym[d.dim_param]
            elif d.dim_param:
                d.dim_param = re.sub(r"s\d+", lambda mm: single.get(mm.group(0), mm.group(0)), d.dim_param)
    onnx.save(m, path)


def _set_metadata(path: str, meta: dict):
    import onnx

    m = onnx.load(path)
    del m.metadata_props[:]
    for k, v in meta.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    onnx.save(m, path)


def export_encoder(model: SkeletonModel, path: str, method: str = "auto") -> str:
    cfg = model.cfg
    wrapper = EncoderExport(model).eval()
    pts = torch.randn(2, 64, 6)
    used = None
    if method in ("auto", "dynamo"):
        try:
            B, N = torch.export.Dim("batch"), torch.export.Dim("num_points")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                torch.onnx.export(wrapper, (pts,), path, dynamo=True, external_data=False, opset_version=OPSET,
                                  input_names=["points"], output_names=["prefix"],
                                  dynamic_shapes={"points": {0: B, 1: N}}, verbose=False)
            used = "dynamo"
        except Exception as e:  # pragma: no cover - depends on the torch version
            if method == "dynamo":
                raise
            print(f"[export] dynamo encoder export failed ({type(e).__name__}: {e}); using TorchScript", file=sys.stderr)
    if used is None:
        torch.onnx.export(wrapper, (pts,), path, dynamo=False, opset_version=17, input_names=["points"],
                          output_names=["prefix"], dynamic_axes={"points": {0: "batch", 1: "num_points"},
                                                                 "prefix": {0: "batch"}})
        used = "torchscript"
    _set_metadata(path, {**_metadata(cfg, "encoder"), "rigserve.exporter": used})
    return used


def export_decoder(model: SkeletonModel, path: str, method: str = "auto") -> str:
    cfg = model.cfg
    wrapper = DecoderExport(model).eval()
    args = example_decoder_inputs(cfg)
    in_names, out_names = decoder_io_names(cfg.dec_layers)
    used = None
    if method in ("auto", "dynamo"):
        try:
            D = torch.export.Dim.DYNAMIC
            kv = {0: D, 2: D}
            dyn = {
                "input_ids": {0: D, 1: D},
                "prefix": {0: D, 1: D},
                "position_ids": {0: D, 1: D},
                "attention_mask": {0: D, 1: D},
                "past_key_values": [kv for _ in range(2 * cfg.dec_layers)],
            }
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                torch.onnx.export(wrapper, args, path, dynamo=True, external_data=False, opset_version=OPSET,
                                  input_names=in_names, output_names=out_names, dynamic_shapes=dyn, verbose=False)
            used = "dynamo"
        except Exception as e:  # pragma: no cover
            if method == "dynamo":
                raise
            print(f"[export] dynamo decoder export failed ({type(e).__name__}: {e}); using TorchScript", file=sys.stderr)
    if used is None:
        axes = {"input_ids": {0: "batch", 1: "seq"}, "prefix": {0: "batch", 1: "prefix_len"},
                "position_ids": {0: "batch", 1: "prefix_plus_seq"}, "attention_mask": {0: "batch", 1: "total_len"},
                "logits": {0: "batch", 1: "seq"}}
        for n in in_names[4:]:
            axes[n] = {0: "batch", 2: "past_len"}
        for n in out_names[1:]:
            axes[n] = {0: "batch", 2: "prefix_len_plus_seq"}
        torch.onnx.export(wrapper, args, path, dynamo=False, opset_version=17, input_names=in_names,
                          output_names=out_names, dynamic_axes=axes)
        used = "torchscript"
    dims = {"input_ids": ["batch", "seq"], "prefix": ["batch", "prefix_len", None],
            "position_ids": ["batch", "prefix_len_plus_seq"], "attention_mask": ["batch", "total_len"],
            "logits": ["batch", "seq", None]}
    for n in in_names[4:]:
        dims[n] = ["batch", None, "past_len", None]
    for n in out_names[1:]:
        dims[n] = ["batch", None, "prefix_len_plus_seq", None]
    _rename_dims(path, dims)
    _set_metadata(path, {**_metadata(cfg, "decoder"), "rigserve.exporter": used})
    return used


def to_fp16(src: str, dst: str):
    """fp16 weights and compute, fp32 inputs/outputs (the contract's I/O types stay fixed)."""
    import onnx
    from onnxruntime.transformers.float16 import convert_float_to_float16

    m = onnx.load(src)
    m16 = convert_float_to_float16(m, keep_io_types=True, disable_shape_infer=False)
    onnx.save(m16, dst)


def to_int8(src: str, dst: str):
    """Dynamic quantization: int8 weights for MatMul/Gemm (activations quantized on the fly)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.ERROR)  # silences the "consider pre-processing" advice
    try:
        quantize_dynamic(src, dst, weight_type=QuantType.QInt8, op_types_to_quantize=["MatMul", "Gemm"],
                         extra_options={"DefaultTensorType": 1})
    finally:
        root.setLevel(level)


def export_all(model: SkeletonModel, out_dir: str, method: str = "auto", variants=("fp16", "int8"), log=print) -> dict:
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)  # "torchvision is not installed" noise
    os.makedirs(out_dir, exist_ok=True)
    model = model.float().eval()
    enc, dec = os.path.join(out_dir, "encoder.onnx"), os.path.join(out_dir, "decoder.onnx")
    info = {"encoder_exporter": export_encoder(model, enc, method), "decoder_exporter": export_decoder(model, dec, method)}
    # The ragged decode step (fp32 weights; a float16 cache with the rigserve op, the
    # default): what the server decodes with when it is there.
    from .step_graph import STEP_FILE, build as build_step, check as check_step

    build_step(model, os.path.join(out_dir, STEP_FILE))
    info["decoder_step_max_abs_diff"] = check_step(model, out_dir)
    for v in variants:
        for src in (enc, dec):
            dst = src.replace(".onnx", f".{v}.onnx")
            (to_fp16 if v == "fp16" else to_int8)(src, dst)
            if v == "int8":
                _set_metadata(dst, {**_metadata(model.cfg, "encoder" if src == enc else "decoder"), "rigserve.variant": "int8"})
    with open(os.path.join(out_dir, "model_config.json"), "w") as f:
        json.dump({"contract": CONTRACT, "config": model.cfg.to_dict(), "head_dim": model.cfg.head_dim,
                   "max_positions": model.cfg.max_positions, "tokens": {
                       "bos": M.BOS, "eos": M.EOS, "pad": M.PAD, "branch": M.BRANCH, "spring": M.SPRING,
                       "mixamo_body": M.MIXAMO_BODY, "mixamo_hand": M.MIXAMO_HAND, "cls_base": M.CLS_BASE,
                       "categories": M.CATEGORIES}, **info}, f, indent=2)
    for fn in sorted(os.listdir(out_dir)):
        if fn.endswith(".onnx"):
            log(f"[export] {fn}: {os.path.getsize(os.path.join(out_dir, fn)) / 1e6:.2f} MB")
    return info


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ckpt", required=True, help="checkpoint from train.py (last.pt / best.pt)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--exporter", choices=["auto", "dynamo", "torchscript"], default="auto")
    ap.add_argument("--variants", default="fp16,int8", help="comma-separated: fp16, int8 (empty for none)")
    a = ap.parse_args(argv)
    torch.set_num_threads(2)
    model, _ = M.load_model(a.ckpt)
    info = export_all(model, a.out, a.exporter, [v for v in a.variants.split(",") if v])
    print(f"[export] done: {info}")


if __name__ == "__main__":
    main()
