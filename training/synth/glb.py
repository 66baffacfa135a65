"""Minimal glTF 2.0 binary (GLB) writing and reading with numpy and struct.

Layout rules followed (glTF 2.0 §4.4, §5.11, GLB container): every bufferView starts on a
4-byte boundary, each accessor has its own tightly packed view (no byteStride needed),
the JSON chunk is padded with spaces and the BIN chunk with zeros to 4 bytes, and
POSITION carries exact float32 min/max."""

from __future__ import annotations

import json
import struct

import numpy as np

GLB_MAGIC = 0x46546C67
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942

ARRAY_BUFFER = 34962
ELEMENT_ARRAY_BUFFER = 34963

COMPONENT = {
    np.dtype(np.int8): 5120,
    np.dtype(np.uint8): 5121,
    np.dtype(np.int16): 5122,
    np.dtype(np.uint16): 5123,
    np.dtype(np.uint32): 5125,
    np.dtype(np.float32): 5126,
}
DTYPE = {v: k for k, v in COMPONENT.items()}
TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


class GltfBuilder:
    def __init__(self):
        self.json: dict = {"asset": {"version": "2.0"}}
        self.bin = bytearray()
        self.accessors: list[dict] = []
        self.views: list[dict] = []

    def add_accessor(self, data: np.ndarray, type_: str, target: int | None = None, minmax: bool = False) -> int:
        data = np.ascontiguousarray(data)
        ncomp = TYPE_COMPONENTS[type_]
        count = data.size // ncomp
        assert data.size == count * ncomp and count > 0
        while len(self.bin) % 4:
            self.bin.append(0)
        view = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": data.nbytes}
        if target is not None:
            view["target"] = target
        self.bin += data.tobytes()
        self.views.append(view)
        acc = {
            "bufferView": len(self.views) - 1,
            "componentType": COMPONENT[data.dtype],
            "count": int(count),
            "type": type_,
        }
        if minmax:
            flat = data.reshape(count, ncomp)
            if data.dtype.kind == "f":
                acc["min"] = [float(x) for x in flat.min(0)]
                acc["max"] = [float(x) for x in flat.max(0)]
            else:
                acc["min"] = [int(x) for x in flat.min(0)]
                acc["max"] = [int(x) for x in flat.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def to_bytes(self) -> bytes:
        while len(self.bin) % 4:
            self.bin.append(0)
        doc = dict(self.json)
        doc["accessors"] = self.accessors
        doc["bufferViews"] = self.views
        doc["buffers"] = [{"byteLength": len(self.bin)}]
        js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
        js += b" " * (-len(js) % 4)
        total = 12 + 8 + len(js) + 8 + len(self.bin)
        out = bytearray(struct.pack("<III", GLB_MAGIC, 2, total))
        out += struct.pack("<II", len(js), CHUNK_JSON) + js
        out += struct.pack("<II", len(self.bin), CHUNK_BIN) + self.bin
        return bytes(out)


# --- reading (tests and tools) -------------------------------------------------------


def read_glb(data: bytes) -> tuple[dict, bytes]:
    magic, version, total = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2 or total != len(data):
        raise ValueError("not a GLB 2.0 container")
    off = 12
    doc, binary = None, b""
    while off < total:
        length, ctype = struct.unpack_from("<II", data, off)
        if length % 4:
            raise ValueError("chunk length not 4-byte aligned")
        chunk = data[off + 8 : off + 8 + length]
        if len(chunk) != length:
            raise ValueError("chunk runs past the end")
        if ctype == CHUNK_JSON:
            doc = json.loads(chunk.decode("utf-8"))
        elif ctype == CHUNK_BIN:
            binary = chunk
        off += 8 + length
    if doc is None:
        raise ValueError("no JSON chunk")
    return doc, binary


def read_accessor(doc: dict, binary: bytes, index: int) -> np.ndarray:
    """An accessor's stored values (integers stay integers), strided views and sparse
    substitution applied, so files from other tools read too (`skeleton/strip_glb.py`)."""
    acc = doc["accessors"][index]
    dt = DTYPE[acc["componentType"]]
    n = TYPE_COMPONENTS[acc["type"]]
    count = acc["count"]
    if "bufferView" in acc:
        view = doc["bufferViews"][acc["bufferView"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        elem = dt.itemsize * n
        stride = view.get("byteStride") or elem
        if stride == elem:
            arr = np.frombuffer(binary, dtype=dt, count=count * n, offset=start).reshape(count, n)
        else:
            raw = np.frombuffer(binary, dtype=np.uint8, count=(count - 1) * stride + elem, offset=start)
            rows = np.lib.stride_tricks.as_strided(raw, shape=(count, elem), strides=(stride, 1))
            arr = np.ascontiguousarray(rows).view(dt).reshape(count, n)
    else:
        arr = np.zeros((count, n), dtype=dt)
    if "sparse" in acc:
        sp = acc["sparse"]
        iv, vv = doc["bufferViews"][sp["indices"]["bufferView"]], doc["bufferViews"][sp["values"]["bufferView"]]
        idx = np.frombuffer(binary, dtype=DTYPE[sp["indices"]["componentType"]], count=sp["count"],
                            offset=iv.get("byteOffset", 0) + sp["indices"].get("byteOffset", 0))
        vals = np.frombuffer(binary, dtype=dt, count=sp["count"] * n,
                             offset=vv.get("byteOffset", 0) + sp["values"].get("byteOffset", 0))
        arr = arr.copy()
        arr[idx] = vals.reshape(-1, n)
    return arr if n > 1 else arr.reshape(-1)


def quat_matrix(q) -> np.ndarray:
    x, y, z, w = (float(c) for c in q)
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def node_local(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    s = np.array(node.get("scale", [1.0, 1.0, 1.0]), dtype=np.float64)
    r = quat_matrix(node["rotation"]) if "rotation" in node else np.eye(3)
    m[:3, :3] = r * s[None, :]
    m[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return m


def world_matrices(doc: dict) -> list[np.ndarray]:
    nodes = doc.get("nodes", [])
    parent = [-1] * len(nodes)
    for i, n in enumerate(nodes):
        for c in n.get("children", []):
            parent[c] = i
    out: list[np.ndarray | None] = [None] * len(nodes)

    def get(i):
        if out[i] is None:
            local = node_local(nodes[i])
            out[i] = local if parent[i] < 0 else get(parent[i]) @ local
        return out[i]

    return [get(i) for i in range(len(nodes))]
