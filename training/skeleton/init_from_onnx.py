"""Recover PyTorch weights from an exported skeleton model (encoder.onnx + decoder.onnx).

    python -m training.skeleton.init_from_onnx --onnx models/skeleton --out models/skeleton

re-exports those weights under the current contract (`export.CONTRACT`) and runs the
export checks on them (ONNX vs PyTorch, cached vs recomputed decoding).

Only the exported ONNX is committed (never checkpoints), so continuing training from a
shipped model starts here. The dynamo exporter keeps most parameter names but folds each
`nn.Linear` weight into a transposed constant (`val_N`) feeding a MatMul; that weight is
found through the bias Add that follows the MatMul.
"""
import json
import os

import onnx
import torch
from onnx import numpy_helper


def _linear_weights(graph):
    """Maps `<module>.weight` -> array for MatMul constants followed by `<module>.bias`."""
    inits = {i.name: i for i in graph.initializer}
    consumers = {}
    for node in graph.node:
        for x in node.input:
            consumers.setdefault(x, []).append(node)
    out = {}
    for node in graph.node:
        if node.op_type not in ("MatMul", "Gemm") or len(node.input) < 2:
            continue
        w = node.input[1]
        if w not in inits or not w.startswith("val_"):
            continue
        for nxt in consumers.get(node.output[0], []):
            if nxt.op_type != "Add":
                continue
            bias = [x for x in nxt.input if x.endswith(".bias") and x in inits]
            if bias:
                out[bias[0][: -len(".bias")] + ".weight"] = numpy_helper.to_array(inits[w]).T
    return out


def _match_bias_free(state, arrays):
    """A Linear without bias (the output head) has no Add to name it: take the one folded
    constant left whose transpose has the parameter's shape, when exactly one has."""
    loose = [a for k, a in arrays.items() if k.startswith("val_") and a.ndim == 2]
    for k, v in state.items():
        if k in arrays or v.ndim != 2:
            continue
        fits = [a for a in loose if tuple(a.T.shape) == tuple(v.shape)]
        if len(fits) == 1:
            arrays[k] = fits[0].T


def load_onnx_weights(model, onnx_dir):
    """Copies every parameter of `model` from the ONNX files; raises if any is missing."""
    arrays = {}
    for part in ("encoder", "decoder"):
        graph = onnx.load(os.path.join(onnx_dir, f"{part}.onnx")).graph
        arrays.update({i.name: numpy_helper.to_array(i) for i in graph.initializer})
        arrays.update(_linear_weights(graph))
    state = model.state_dict()
    _match_bias_free(state, arrays)
    missing = []
    for k, v in state.items():
        a = arrays.get(k)
        if a is None or tuple(a.shape) != tuple(v.shape):
            missing.append(k)
            continue
        state[k] = torch.from_numpy(a.copy()).to(v.dtype)
    if missing:
        raise ValueError(f"{len(missing)} parameters not recovered from {onnx_dir}: {missing[:8]}")
    model.load_state_dict(state)
    return model


def config_of(onnx_dir):
    with open(os.path.join(onnx_dir, "model_config.json")) as f:
        return json.load(f)["config"]


def main(argv=None):
    import argparse
    import tempfile

    import numpy as np

    from . import model as M
    from .check_export import OnnxSkeleton, check, greedy_recompute, sample_inputs
    from .export import export_all

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--onnx", required=True, help="folder with encoder.onnx, decoder.onnx, model_config.json")
    ap.add_argument("--out", required=True, help="where to write the re-exported files (may be --onnx)")
    ap.add_argument("--variants", default="", help="comma-separated: fp16, int8")
    a = ap.parse_args(argv)
    torch.set_num_threads(2)
    model = M.SkeletonModel(M.ModelConfig.from_dict(config_of(a.onnx))).eval()
    load_onnx_weights(model, a.onnx)
    # Export beside, check, then move into place: a failed check leaves --out untouched.
    tmp = tempfile.mkdtemp(prefix="reexport_")
    export_all(model, tmp, variants=[v for v in a.variants.split(",") if v])
    res = check(model, tmp, steps=24, n_points=2048)
    # The files read must give what the files written give (any contract: a decoder's
    # first output is always the logits, and a recompute needs no cache).
    old = OnnxSkeleton(os.path.join(a.onnx, "encoder.onnx"), os.path.join(a.onnx, "decoder.onnx"))
    new = OnnxSkeleton(os.path.join(tmp, "encoder.onnx"), os.path.join(tmp, "decoder.onnx"))
    pts, prompts = sample_inputs(model.cfg, None, 2048)
    _, l_old = greedy_recompute(old, old.encode(pts), prompts, 12)
    _, l_new = greedy_recompute(new, new.encode(pts), prompts, 12)
    res["old_vs_new_max_logit_diff"] = float(np.abs(l_old - l_new).max())
    res["ok"] = res["ok"] and res["old_vs_new_max_logit_diff"] <= 1e-3
    print(json.dumps({k: v for k, v in res.items() if not isinstance(v, dict)}, indent=1))
    if not res["ok"]:
        raise SystemExit("export check failed; nothing written")
    os.makedirs(a.out, exist_ok=True)
    names = sorted(os.listdir(tmp))
    for fn in names:
        os.replace(os.path.join(tmp, fn), os.path.join(a.out, fn))
    print(f"[init_from_onnx] wrote {names} to {a.out}")


if __name__ == "__main__":
    main()
