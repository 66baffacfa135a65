"""The ragged decode-step graph, `decoder_step.onnx` (see ONNX_CONTRACT.md, "Decode step").

    python -m training.skeleton.step_graph --onnx models/skeleton      # writes decoder_step.onnx, checks it

`decoder.onnx` reads every row's cache up to the longest row in the batch: rows that joined
later are left-padded, and under load more than half of the cache a step reads is padding.
On a CPU the decode step is bound by reading the cache, so that padding is paid in full.
This graph runs one token per row through an attention op that attends over each row's own
length (`seqlens_k`) and, when the past and present buffers are the same memory, writes the
new key and value into the buffer in place. Rows are right-padded: row b's positions are
columns 0..seqlens_k[b]-1.

The shipped graph uses rigserve's own op, `ai.rigserve.RaggedAttention`, which the server
registers (src/infer/attention_op.rs): it is ONNX Runtime's `GroupQueryAttention`
(`com.microsoft`) in inputs, outputs and numbers, without that op's per-head matrix
packing, which took 64 % of a batch-16 step. Stock ONNX Runtime (this Python side) cannot
run it, so `check()` runs the `GroupQueryAttention` twin built from the same weights and
checks that the shipped file is that twin with only the attention nodes swapped; the Rust
tests (`tests/infer.rs`) check the shipped file against `decoder.onnx`.

The rigserve flavour keeps its cache in half precision (`float16` past and present; q, k,
v and everything else stay `float`): the op rounds each new key and value as it writes them
and computes in `float`, and a batch-16 step, which reads every row's whole cache, got a
third faster on a 32 MiB-L3 CPU (README). `--cache float32` keeps a `float` cache;
`GroupQueryAttention` needs one.

The graph is written directly with `onnx.helper` from the PyTorch weights (the exporters do
not emit contrib ops); `check()` compares its logits with the PyTorch model.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
import torch
from onnx import TensorProto, helper, numpy_helper

from . import model as M

STEP_FILE = "decoder_step.onnx"
CONTRACT = "skeleton-v2"
# The attention op of each flavour: (op_type, domain).
ATTENTION = {"rigserve": ("RaggedAttention", "ai.rigserve"), "gqa": ("GroupQueryAttention", "com.microsoft")}
# The cache tensors' first axis: rigserve's op lets the cache hold more rows ("slots") than
# the batch, GroupQueryAttention needs them equal ("batch", the name the other inputs use).
CACHE_ROWS = {"rigserve": "slots", "gqa": "batch"}
# Metadata naming the flavour, which tells the server whether the cache may have spare slots.
ATTENTION_KEY = "rigserve.attention"
# The cache's number type: each flavour's default; GroupQueryAttention takes only float.
CACHE_TYPES = {"float32": TensorProto.FLOAT, "float16": TensorProto.FLOAT16}
CACHE_DEFAULT = {"rigserve": "float16", "gqa": "float32"}


def cache_type(attention: str, cache: str | None) -> int:
    """The ONNX element type of the cache tensors for a flavour (None: its default)."""
    cache = cache or CACHE_DEFAULT[attention]
    if attention == "gqa" and cache != "float32":
        raise ValueError("GroupQueryAttention keeps its cache in float32")
    return CACHE_TYPES[cache]


def is_cache(name: str) -> bool:
    return name.startswith(("past_key_values.", "present."))


def attention_node(attention: str, qkv: str, past: list, outputs: list, heads: int, scale: float):
    """One layer's attention node of the given flavour. `past` is (past key, past value,
    seqlens_k, total_sequence_length); GQA's separate key and value inputs stay empty, as
    q, k and v come packed."""
    op_type, op_domain = ATTENTION[attention]
    if attention == "gqa":
        return helper.make_node(op_type, [qkv, "", "", *past], outputs, domain=op_domain, scale=scale,
                                num_heads=heads, kv_num_heads=heads)
    return helper.make_node(op_type, [qkv, *past], outputs, domain=op_domain, scale=scale, num_heads=heads)


def step_io_names(n_layers: int):
    past = [f"past_key_values.{i}.{kv}" for i in range(n_layers) for kv in ("key", "value")]
    present = [f"present.{i}.{kv}" for i in range(n_layers) for kv in ("key", "value")]
    return ["input_ids", "position_ids", "seqlens_k", "total_sequence_length", *past], ["logits", *present]


def build(model: M.SkeletonModel, path: str, attention: str = "rigserve", cache: str | None = None) -> str:
    op_domain = ATTENTION[attention][1]
    cache_elem = cache_type(attention, cache)
    cfg = model.cfg
    dec = model.decoder
    d, h, dh, n = cfg.d_model, cfg.n_heads, cfg.head_dim, cfg.dec_layers
    inits, nodes = [], []

    def const(name, arr):
        inits.append(numpy_helper.from_array(np.ascontiguousarray(arr, dtype=np.float32), name))
        return name

    def t(x):
        return x.detach().float().cpu().numpy()

    def linear(x, lin, name, out):
        nodes.append(helper.make_node("MatMul", [x, const(f"{name}.w", t(lin.weight).T)], [f"{name}.mm"]))
        if lin.bias is not None:
            nodes.append(helper.make_node("Add", [f"{name}.mm", const(f"{name}.b", t(lin.bias))], [out]))
        else:
            nodes.append(helper.make_node("Identity", [f"{name}.mm"], [out]))
        return out

    def layer_norm(x, ln, name, out):
        nodes.append(helper.make_node("LayerNormalization", [x, const(f"{name}.g", t(ln.weight)),
                                                             const(f"{name}.b", t(ln.bias))], [out],
                                      axis=-1, epsilon=ln.eps))
        return out

    nodes.append(helper.make_node("Gather", [const("tok", t(dec.tok.weight)), "input_ids"], ["emb_tok"]))
    nodes.append(helper.make_node("Gather", [const("pos", t(dec.pos.weight)), "position_ids"], ["emb_pos"]))
    nodes.append(helper.make_node("Add", ["emb_tok", "emb_pos"], ["x0"]))
    x = "x0"
    for i, layer in enumerate(dec.layers):
        a = layer.attn
        p = f"l{i}"
        hn = layer_norm(x, layer.ln1, f"{p}.ln1", f"{p}.h")
        # q, k and v in one MatMul: GQA takes them packed along the last axis.
        w = np.concatenate([t(a.q.weight).T, t(a.k.weight).T, t(a.v.weight).T], axis=1)
        b = np.concatenate([t(a.q.bias), t(a.k.bias), t(a.v.bias)])
        nodes.append(helper.make_node("MatMul", [hn, const(f"{p}.qkv.w", w)], [f"{p}.qkv.mm"]))
        nodes.append(helper.make_node("Add", [f"{p}.qkv.mm", const(f"{p}.qkv.b", b)], [f"{p}.qkv"]))
        past = [f"past_key_values.{i}.key", f"past_key_values.{i}.value", "seqlens_k", "total_sequence_length"]
        nodes.append(attention_node(attention, f"{p}.qkv", past, [f"{p}.att", f"present.{i}.key", f"present.{i}.value"],
                                    h, 1.0 / float(np.sqrt(dh))))
        o = linear(f"{p}.att", a.o, f"{p}.o", f"{p}.o.out")
        nodes.append(helper.make_node("Add", [x, o], [f"{p}.x1"]))
        h2 = layer_norm(f"{p}.x1", layer.ln2, f"{p}.ln2", f"{p}.h2")
        f1 = linear(h2, layer.ff.fc1, f"{p}.fc1", f"{p}.f1")
        # tanh GELU, as in training (FastGelu is that formula).
        nodes.append(helper.make_node("FastGelu", [f1], [f"{p}.g"], domain="com.microsoft"))
        f2 = linear(f"{p}.g", layer.ff.fc2, f"{p}.fc2", f"{p}.f2")
        nodes.append(helper.make_node("Add", [f"{p}.x1", f2], [f"{p}.x2"]))
        x = f"{p}.x2"
    xf = layer_norm(x, dec.ln_f, "ln_f", "xf")
    linear(xf, dec.head, "head", "logits")

    ins, outs = step_io_names(n)
    cache_shape = [CACHE_ROWS[attention], h, "capacity", dh]
    inputs = [
        helper.make_tensor_value_info("input_ids", TensorProto.INT64, ["batch", 1]),
        helper.make_tensor_value_info("position_ids", TensorProto.INT64, ["batch", 1]),
        helper.make_tensor_value_info("seqlens_k", TensorProto.INT32, ["batch"]),
        helper.make_tensor_value_info("total_sequence_length", TensorProto.INT32, []),
        *[helper.make_tensor_value_info(nm, cache_elem, cache_shape) for nm in ins[4:]],
    ]
    outputs = [helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["batch", 1, cfg.vocab_size]),
               *[helper.make_tensor_value_info(nm, cache_elem, cache_shape) for nm in outs[1:]]]
    graph = helper.make_graph(nodes, "skeleton_decoder_step", inputs, outputs, initializer=inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18), helper.make_opsetid("com.microsoft", 1),
                                                *([helper.make_opsetid(op_domain, 1)] if attention != "gqa" else [])],
                          producer_name="rigserve training/skeleton/step_graph.py")
    m.ir_version = 10  # what onnxruntime 1.31 reads
    meta = {
        "rigserve.contract": CONTRACT, "rigserve.part": "decoder_step", "d_model": cfg.d_model,
        "n_latents": cfg.n_latents, "n_layers": n, "n_heads": h, "head_dim": dh, "vocab_size": cfg.vocab_size,
        "max_positions": cfg.max_positions, "max_tokens": cfg.max_tokens, "rigserve.config": json.dumps(cfg.to_dict()),
        ATTENTION_KEY: attention,
    }
    for k, v in meta.items():
        e = m.metadata_props.add()
        e.key, e.value = k, str(v)
    with open(path, "wb") as f:
        f.write(m.SerializeToString())
    return path


def attention_of(path: str) -> str:
    """Which flavour of attention a step file uses."""
    import onnx

    types = {(n.op_type, n.domain) for n in onnx.load(path).graph.node}
    found = [k for k, v in ATTENTION.items() if v in types]
    if len(found) != 1:
        raise AssertionError(f"{path}: expected one kind of attention node, found {found}")
    return found[0]


def cache_of(path: str) -> str:
    """The number type of a step file's cache tensors."""
    import onnx

    types = {v.type.tensor_type.elem_type for v in onnx.load(path).graph.input if is_cache(v.name)}
    names = [k for k, v in CACHE_TYPES.items() if {v} == types]
    if not names:
        raise AssertionError(f"{path}: cache tensors of types {types}")
    return names[0]


def convert(path: str, attention: str = "rigserve", cache: str | None = None) -> str:
    """Rewrites a step file's attention nodes and cache type, in place, to the given flavour
    (cache None: the flavour's default): no weights needed (a file whose PyTorch weights
    cannot be recovered still converts)."""
    import onnx

    cache_elem = cache_type(attention, cache)
    m = onnx.load(path)
    op_domain = ATTENTION[attention][1]
    for n in m.graph.node:
        if (n.op_type, n.domain) not in ATTENTION.values():
            continue
        real = [x for x in n.input if x]  # qkv, past key, past value, seqlens_k, total length
        scale = next(a.f for a in n.attribute if a.name == "scale")
        heads = next(a.i for a in n.attribute if a.name == "num_heads")
        n.CopyFrom(attention_node(attention, real[0], real[1:], list(n.output), heads, scale))
    if attention != "gqa" and all(o.domain != op_domain for o in m.opset_import):
        m.opset_import.append(helper.make_opsetid(op_domain, 1))
    for v in list(m.graph.input) + list(m.graph.output):
        if is_cache(v.name):
            v.type.tensor_type.shape.dim[0].dim_param = CACHE_ROWS[attention]
            v.type.tensor_type.elem_type = cache_elem
    meta = {p.key: p for p in m.metadata_props}
    entry = meta.get(ATTENTION_KEY) or m.metadata_props.add()
    entry.key, entry.value = ATTENTION_KEY, attention
    onnx.save(m, path)
    return path


def same_but_attention(a_path: str, b_path: str) -> None:
    """Raises unless the two step files have the same weights, I/O and nodes, the attention
    nodes apart (which must read the same past, seqlens and qkv, and write the same outputs)."""
    import onnx

    a, b = onnx.load(a_path).graph, onnx.load(b_path).graph

    def nodes(g):
        att = set(ATTENTION.values())
        return [("attention" if (n.op_type, n.domain) in att else (n.op_type, n.domain),
                 [x for x in n.input if x], list(n.output)) for n in g.node]

    if nodes(a) != nodes(b):
        raise AssertionError(f"{a_path} and {b_path} differ in more than their attention nodes")
    wa = {t.name: numpy_helper.to_array(t) for t in a.initializer}
    wb = {t.name: numpy_helper.to_array(t) for t in b.initializer}
    if wa.keys() != wb.keys() or any(not np.array_equal(wa[k], wb[k]) for k in wa):
        raise AssertionError(f"{a_path} and {b_path} have different weights")
    def io(g):  # names, types and ranks (the first axis and the cache's type go with the flavour)
        return [(x.name, None if is_cache(x.name) else x.type.tensor_type.elem_type, len(x.type.tensor_type.shape.dim))
                for x in [*g.input, *g.output]]

    if io(a) != io(b):
        raise AssertionError(f"{a_path} and {b_path} have different inputs or outputs")


def check(model: M.SkeletonModel, onnx_dir: str, rows: int = 5, seed: int = 0, tol: float = 1e-3) -> float:
    """Checks `decoder_step.onnx` in `onnx_dir`: run as is when it uses `GroupQueryAttention`;
    when it uses rigserve's op, as its `GroupQueryAttention` twin built from `model` (after
    checking that the two files differ only in their attention nodes and cache type; the
    half-precision cache itself is checked in Rust, tests/infer.rs)."""
    import tempfile

    path = os.path.join(onnx_dir, STEP_FILE)
    if attention_of(path) == "gqa":
        return check_logits(model, path, rows, seed, tol)
    with tempfile.TemporaryDirectory() as tmp:
        twin = build(model, os.path.join(tmp, STEP_FILE), attention="gqa")
        same_but_attention(path, twin)
        return check_logits(model, twin, rows, seed, tol)


def check_logits(model: M.SkeletonModel, path: str, rows: int = 5, seed: int = 0, tol: float = 1e-3) -> float:
    """Logits of a (`GroupQueryAttention`) step graph for a ragged batch (rows of different
    lengths, the cache right-padded, the past and present bound to one buffer so the op
    writes in place) against PyTorch's full-sequence logits. Returns the largest
    difference; raises when it passes `tol` or when the new keys were not written where the
    contract says."""
    import onnxruntime as ort

    cfg = model.cfg
    rng = np.random.default_rng(seed)
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.log_severity_level = 3
    sess = ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
    lat, h, dh, n = cfg.n_latents, cfg.n_heads, cfg.head_dim, cfg.dec_layers
    lens = [int(x) for x in rng.integers(2, 12, size=rows)]
    toks = [rng.integers(0, cfg.vocab_size, size=k + 1) for k in lens]  # the last one is the step's token
    pts = torch.from_numpy(rng.uniform(-1, 1, size=(rows, 64, 6)).astype(np.float32))
    with torch.no_grad():
        prefix = model.encoder(pts)
        # Reference: the full causal sequence [prefix ; tokens], logits at the last token.
        want = [model.decoder.forward_train(prefix[b:b + 1], torch.from_numpy(toks[b][None]).long())[0, -1].numpy()
                for b in range(rows)]
        # The cache: each row's own prefill (no padding), placed at columns 0..len-1.
        cap = max(lat + k for k in lens) + 3
        bufs = [np.zeros((rows, h, cap, dh), np.float32) for _ in range(2 * n)]
        for b in range(rows):
            k = lens[b]
            ids = torch.from_numpy(toks[b][None, :k]).long()
            posn = torch.arange(lat + k)[None]
            mask = torch.ones(1, lat + k, dtype=torch.long)
            empty = [(torch.zeros(1, h, 0, dh), torch.zeros(1, h, 0, dh)) for _ in range(n)]
            _, new = model.decoder.forward_cached(ids, prefix[b:b + 1], posn, mask, empty)
            for i, (nk, nv) in enumerate(new):
                bufs[2 * i][b, :, :lat + k] = nk[0].numpy()
                bufs[2 * i + 1][b, :, :lat + k] = nv[0].numpy()
    seqlens = np.array([lat + k for k in lens], np.int32)
    ins, outs = step_io_names(n)
    io = sess.io_binding()
    io.bind_cpu_input("input_ids", np.array([[t[-1]] for t in toks], np.int64))
    io.bind_cpu_input("position_ids", seqlens[:, None].astype(np.int64))
    io.bind_cpu_input("seqlens_k", seqlens)
    io.bind_cpu_input("total_sequence_length", np.array(int(seqlens.max()) + 1, np.int32))
    io.bind_output("logits")
    vals = [ort.OrtValue.ortvalue_from_numpy(buf) for buf in bufs]
    for name, v in zip(ins[4:], vals):
        io.bind_ortvalue_input(name, v)
    for name, v in zip(outs[1:], vals):
        io.bind_ortvalue_output(name, v)
    sess.run_with_iobinding(io)
    got = io.copy_outputs_to_cpu()[0][:, 0]
    diff = float(max(np.abs(got[b] - want[b]).max() for b in range(rows)))
    if diff > tol:
        raise AssertionError(f"decode step logits differ from PyTorch by {diff:.2e}")
    # In place: each row's new key is at column seqlens[b], and nothing past it was written.
    after = vals[0].numpy()
    if not all(np.any(after[b, :, seqlens[b]] != 0) for b in range(rows)):
        raise AssertionError("the new keys were not written at column seqlens_k")
    if not all(np.all(after[b, :, seqlens[b] + 1:] == 0) for b in range(rows)):
        raise AssertionError("the step wrote past a row's new column")
    return diff


def main(argv=None):
    from .init_from_onnx import config_of, load_onnx_weights

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--onnx", help="model folder with encoder.onnx / decoder.onnx; decoder_step.onnx is written there")
    ap.add_argument("--convert", metavar="FILE", help="instead: swap the attention nodes of an existing step file")
    ap.add_argument("--attention", choices=sorted(ATTENTION), default="rigserve",
                    help="rigserve: the server's own op (default); gqa: stock ONNX Runtime's GroupQueryAttention")
    ap.add_argument("--cache", choices=sorted(CACHE_TYPES), default=None,
                    help="the cache's number type (default: float16 with rigserve's op, float32 with gqa)")
    a = ap.parse_args(argv)
    if a.convert:
        convert(a.convert, a.attention, a.cache)
        print(f"[step] {a.convert}: attention is now {attention_of(a.convert)}, cache {cache_of(a.convert)}")
        return 0
    if not a.onnx:
        ap.error("--onnx or --convert is required")
    model = M.SkeletonModel(M.ModelConfig.from_dict(config_of(a.onnx)))
    load_onnx_weights(model, a.onnx)
    model.eval()
    path = build(model, os.path.join(a.onnx, STEP_FILE), attention=a.attention, cache=a.cache)
    diff = check(model, a.onnx)
    print(f"[step] wrote {path} ({os.path.getsize(path) / 1e6:.1f} MB); logits vs PyTorch within {diff:.2e}")


if __name__ == "__main__":
    sys.exit(main())
