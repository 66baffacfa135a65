"""Recover PyTorch weights from an exported skeleton model (encoder.onnx + decoder.onnx).

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
