"""Exports a trained skin checkpoint to ONNX (the `skin-v1` contract, ONNX_CONTRACT.md).

    python -m training.skin.export --ckpt /root/rigserve_runs/skin_v1/last.pt --out models/skin

writes `skin.onnx` (fp32), `skin.fp16.onnx` (fp16 weights and compute, fp32 inputs and
outputs) and `model_config.json`, then checks both against PyTorch with ONNX Runtime.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
import onnx
import torch

from .model import BONE_FEATURES, PAIR_FEATURES, VERT_FEATURES, SkinConfig, SkinModel

OPSET = 18
CONTRACT = "skin-v1"
INPUTS = ["vert", "bone", "cand", "pair"]


def example_inputs(rows=37, bones=9, k=8, seed=0):
    g = torch.Generator().manual_seed(seed)
    vert = torch.rand(rows, VERT_FEATURES, generator=g) * 2 - 1
    bone = torch.rand(bones, BONE_FEATURES, generator=g) * 2 - 1
    cand = torch.randint(0, bones, (rows, k), generator=g)
    cand[::3, k - 2:] = -1
    pair = torch.rand(rows, k, PAIR_FEATURES, generator=g)
    pair[..., 2] = pair[..., 2] / pair[..., 2].sum(-1, keepdim=True)
    return vert, bone, cand, pair


def export_onnx(model: SkinModel, path: str, step: int = 0):
    model = model.eval()
    args = example_inputs()
    dyn = {"vert": {0: "rows"}, "bone": {0: "bones"}, "cand": {0: "rows", 1: "k"}, "pair": {0: "rows", 1: "k"},
           "weights": {0: "rows", 1: "k"}}
    with torch.no_grad():
        torch.onnx.export(model, args, path, dynamo=False, opset_version=OPSET, input_names=INPUTS,
                          output_names=["weights"], dynamic_axes=dyn)
    m = onnx.load(path)
    meta = {"rigserve.contract": CONTRACT, "rigserve.exporter": f"training.skin.export step {step}",
            "vert_features": str(VERT_FEATURES), "bone_features": str(BONE_FEATURES),
            "pair_features": str(PAIR_FEATURES), **{k: str(v) for k, v in model.cfg.to_dict().items()}}
    for k, v in meta.items():
        e = m.metadata_props.add()
        e.key, e.value = k, v
    onnx.checker.check_model(m)
    onnx.save(m, path)


def to_fp16(src: str, dst: str):
    from onnxruntime.transformers.float16 import convert_float_to_float16

    m = onnx.load(src)
    m16 = convert_float_to_float16(m, keep_io_types=True, disable_shape_infer=False)
    onnx.save(m16, dst)


def max_diff(model: SkinModel, path: str, shapes=((37, 9, 8), (1, 1, 1), (500, 60, 12), (3, 2, 5))) -> float:
    """Largest |ONNX Runtime - PyTorch| over inputs of several row, bone and candidate counts."""
    import onnxruntime as ort

    s = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    worst = 0.0
    for i, (r, b, k) in enumerate(shapes):
        args = example_inputs(r, b, k, seed=i + 1)
        with torch.no_grad():
            ref = model(*args).numpy()
        got = s.run(None, {n: a.numpy() for n, a in zip(INPUTS, args)})[0]
        if got.shape != ref.shape:
            raise AssertionError(f"{path}: shape {got.shape} vs {ref.shape}")
        worst = max(worst, float(np.abs(got - ref).max()))
    return worst


def load_checkpoint(path: str):
    ck = torch.load(path, map_location="cpu", weights_only=False)
    model = SkinModel(SkinConfig.from_dict(ck["config"]))
    model.load_state_dict(ck["model"])
    return model.eval(), ck.get("step", 0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ckpt", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--no-fp16", action="store_true")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    model, step = load_checkpoint(a.ckpt)
    os.makedirs(a.out, exist_ok=True)
    p32 = os.path.join(a.out, "skin.onnx")
    export_onnx(model, p32, step)
    report = {"step": step, "config": model.cfg.to_dict(), "params": model.num_params(),
              "max_abs_diff_fp32": max_diff(model, p32)}
    if not a.no_fp16:
        p16 = os.path.join(a.out, "skin.fp16.onnx")
        to_fp16(p32, p16)
        report["max_abs_diff_fp16"] = max_diff(model, p16)
    with open(os.path.join(a.out, "model_config.json"), "w") as f:
        json.dump(report, f, indent=2)
    print(json.dumps(report, indent=2), file=sys.stderr)


if __name__ == "__main__":
    main()
