"""Copies the `train` rigs of a data set keeping only what `rigserve dataset` reads.

    python3 -m training.skeleton.strip_glb ../shared/rigs /tmp/rigs_s

It reads and writes with `training.synth.glb`, the synthetic generator's GLB module.
Kept: positions, joints, weights (as normalised uint16), indices, nodes and skins. Dropped: materials, textures, normals (samples take face normals), UVs, colours,
animations and morph targets. The 140 `train` rigs go from 53 MB to 18.6 MB (5.4 MB
gzipped), so they fit the device tool's 64 MiB working tree; `rigserve dataset` on the
copies gives the same tokens and, but for the weights' rounding, the same samples.
The copies are third-party data: they stay out of git like the originals.
"""

from __future__ import annotations

import os
import sys

import numpy as np

from training.synth.glb import ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, GltfBuilder, read_accessor, read_glb


def values(doc: dict, binary: bytes, index: int) -> np.ndarray:
    """An accessor as rows (count, components); normalised integers as floats."""
    arr = read_accessor(doc, binary, index)
    arr = arr.reshape(doc["accessors"][index]["count"], -1)
    if doc["accessors"][index].get("normalized") and arr.dtype.kind in "iu":
        arr = np.maximum(arr.astype(np.float32) / np.iinfo(arr.dtype).max, -1.0)
    return arr


def strip(src: str, dst: str) -> None:
    with open(src, "rb") as f:
        doc, binary = read_glb(f.read())
    out = GltfBuilder()
    for m in doc.get("meshes", []):
        m.pop("extras", None)
        for p in m["primitives"]:
            attrs = {}
            for k, v in p["attributes"].items():
                if k == "POSITION":
                    attrs[k] = out.add_accessor(values(doc, binary, v).astype(np.float32), "VEC3", ARRAY_BUFFER, minmax=True)
                elif k.startswith("JOINTS_"):
                    j = values(doc, binary, v)
                    attrs[k] = out.add_accessor(j.astype(np.uint8 if j.max(initial=0) < 256 else np.uint16), "VEC4",
                                                ARRAY_BUFFER)
                elif k.startswith("WEIGHTS_"):
                    w = np.nan_to_num(values(doc, binary, v).astype(np.float64))
                    q = np.round(np.clip(w, 0, 1) * 65535).astype(np.uint16)
                    attrs[k] = out.add_accessor(q, "VEC4", ARRAY_BUFFER)
                    out.accessors[attrs[k]]["normalized"] = True
            p["attributes"] = attrs
            if "indices" in p:
                idx = values(doc, binary, p["indices"]).reshape(-1)
                p["indices"] = out.add_accessor(idx.astype(np.uint32 if idx.max(initial=0) > 65535 else np.uint16),
                                                "SCALAR", ELEMENT_ARRAY_BUFFER)
            for key in ("material", "targets", "extensions", "extras"):
                p.pop(key, None)
        m.pop("weights", None)
    for s in doc.get("skins", []):
        if "inverseBindMatrices" in s:
            ibm = values(doc, binary, s["inverseBindMatrices"]).astype(np.float32)
            s["inverseBindMatrices"] = out.add_accessor(ibm, "MAT4")
    for n in doc.get("nodes", []):
        for key in ("weights", "camera", "extensions"):
            n.pop(key, None)
    for key in ("animations", "materials", "textures", "images", "samplers", "cameras", "extensionsRequired",
                "extensionsUsed", "extensions"):
        doc.pop(key, None)
    out.json = doc
    with open(dst, "wb") as f:
        f.write(out.to_bytes())


def main(argv: list[str]) -> None:
    src_dir, dst_dir = argv
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


if __name__ == "__main__":
    main(sys.argv[1:])
