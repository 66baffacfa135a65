"""Copies the `train` rigs of a data set keeping only what `rigserve dataset` reads.

    python3 training/skeleton/strip_glb.py ../shared/rigs /tmp/rigs_s

Kept: positions, joints, weights (as normalised uint16), indices, nodes and skins.
Dropped: materials, textures, normals (samples take face normals), UVs, colours,
animations and morph targets. The 140 `train` rigs go from 63 MB to 18 MB (5.4 MB
gzipped), so they fit the device tool's 64 MiB working tree; `rigserve dataset` on the
copies gives the same tokens and, but for the weights' rounding, the same samples.
The copies are third-party data: they stay out of git like the originals.
"""

from __future__ import annotations

import json
import os
import struct
import sys

import numpy as np

CT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
NC = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}

def read_glb(path):
    b = open(path, "rb").read()
    jl = struct.unpack("<I", b[12:16])[0]
    j = json.loads(b[20:20 + jl])
    o = 20 + jl
    binc = b""
    if o < len(b):
        bl = struct.unpack("<I", b[o:o + 4])[0]
        binc = b[o + 8:o + 8 + bl]
    return j, binc

def read_accessor(j, binc, i):
    a = j["accessors"][i]
    dt = np.dtype(CT[a["componentType"]]).newbyteorder("<")
    nc = NC[a["type"]]
    n = a["count"]
    out = np.zeros((n, nc), dtype=dt)
    if "bufferView" in a:
        bv = j["bufferViews"][a["bufferView"]]
        assert bv.get("buffer", 0) == 0
        base = bv.get("byteOffset", 0) + a.get("byteOffset", 0)
        es = dt.itemsize * nc
        stride = bv.get("byteStride", es) or es
        raw = np.frombuffer(binc, dtype=np.uint8, count=(n - 1) * stride + es if n else 0, offset=base)
        if n:
            rows = np.lib.stride_tricks.as_strided(raw, shape=(n, es), strides=(stride, 1))
            out = np.ascontiguousarray(rows).view(dt).reshape(n, nc)
    if "sparse" in a:
        s = a["sparse"]
        ib = j["bufferViews"][s["indices"]["bufferView"]]
        idx = np.frombuffer(binc, dtype=np.dtype(CT[s["indices"]["componentType"]]).newbyteorder("<"), count=s["count"],
                            offset=ib.get("byteOffset", 0) + s["indices"].get("byteOffset", 0))
        vb = j["bufferViews"][s["values"]["bufferView"]]
        vals = np.frombuffer(binc, dtype=dt, count=s["count"] * nc,
                             offset=vb.get("byteOffset", 0) + s["values"].get("byteOffset", 0)).reshape(-1, nc)
        out = out.copy()
        out[idx] = vals
    if a.get("normalized") and dt != np.float32:
        info = np.iinfo(dt)
        out = np.maximum(out.astype(np.float32) / info.max, -1.0)
    return out

def strip(src, dst):
    j, binc = read_glb(src)
    new_bin = bytearray()
    views, accs = [], []
    def put(arr, target=None, extra=None):
        arr = np.ascontiguousarray(arr)
        while len(new_bin) % 4:
            new_bin.append(0)
        v = {"buffer": 0, "byteOffset": len(new_bin), "byteLength": arr.nbytes}
        if target:
            v["target"] = target
        new_bin.extend(arr.tobytes())
        views.append(v)
        rev = {v: k for k, v in CT.items()}
        acc = {"bufferView": len(views) - 1, "componentType": rev[arr.dtype.type], "count": arr.shape[0],
               "type": {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}[arr.shape[1]]}
        acc.update(extra or {})
        accs.append(acc)
        return len(accs) - 1
    for m in j.get("meshes", []):
        m.pop("extras", None)
        for p in m["primitives"]:
            attrs = {}
            for k, v in p["attributes"].items():
                if k == "POSITION":
                    arr = read_accessor(j, binc, v).astype(np.float32)
                    attrs[k] = put(arr, 34962, {"min": arr.min(0).tolist(), "max": arr.max(0).tolist()})
                elif k.startswith("JOINTS_"):
                    arr = read_accessor(j, binc, v)
                    t = np.uint8 if arr.max(initial=0) < 256 else np.uint16
                    attrs[k] = put(arr.astype(t), 34962)
                elif k.startswith("WEIGHTS_"):
                    w = np.nan_to_num(read_accessor(j, binc, v).astype(np.float64))
                    q = np.round(np.clip(w, 0, 1) * 65535).astype(np.uint16)
                    attrs[k] = put(q, 34962, {"normalized": True})
            p["attributes"] = attrs
            if "indices" in p:
                idx = read_accessor(j, binc, p["indices"]).reshape(-1, 1)
                p["indices"] = put(idx.astype(np.uint32 if idx.max(initial=0) > 65535 else np.uint16), 34963)
            for key in ("material", "targets", "extensions", "extras"):
                p.pop(key, None)
        m.pop("weights", None)
    for s in j.get("skins", []):
        if "inverseBindMatrices" in s:
            s["inverseBindMatrices"] = put(read_accessor(j, binc, s["inverseBindMatrices"]).astype(np.float32))
    for n in j.get("nodes", []):
        n.pop("weights", None)
        n.pop("camera", None)
        n.pop("extensions", None)
    for k in ("animations", "materials", "textures", "images", "samplers", "cameras", "extensionsRequired",
              "extensionsUsed", "extensions"):
        j.pop(k, None)
    while len(new_bin) % 4:
        new_bin.append(0)
    j["buffers"] = [{"byteLength": len(new_bin)}]
    j["bufferViews"] = views
    j["accessors"] = accs
    js = json.dumps(j, separators=(",", ":")).encode()
    js += b" " * ((4 - len(js) % 4) % 4)
    total = 12 + 8 + len(js) + 8 + len(new_bin)
    with open(dst, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, total))
        f.write(struct.pack("<I", len(js)) + b"JSON" + js)
        f.write(struct.pack("<I", len(new_bin)) + b"BIN\x00" + bytes(new_bin))

if __name__ == "__main__":
    src_dir, dst_dir = sys.argv[1], sys.argv[2]
    os.makedirs(dst_dir, exist_ok=True)
    keep = set()
    lines = open(os.path.join(src_dir, "manifest.tsv")).read().splitlines()
    out_lines = [lines[0]]
    hdr = lines[0].split("\t")
    for ln in lines[1:]:
        f = dict(zip(hdr, ln.split("\t")))
        if f.get("split") == "train":
            out_lines.append(ln)
            keep.add(f[hdr[0]])
    open(os.path.join(dst_dir, "manifest.tsv"), "w").write("\n".join(out_lines) + "\n")
    for name in sorted(keep):
        strip(os.path.join(src_dir, name), os.path.join(dst_dir, name))
    print(len(keep), "files")
