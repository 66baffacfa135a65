"""Minimal glTF/GLB reading, writing and rig checks (numpy + standard library).

Used by the corpus collector: pack a .gltf (external buffers and images) into one GLB,
read skins and weights, renormalise weights, and check a rig is usable for training."""
import base64
import json
import os
import struct

import numpy as np

GLB_MAGIC = b"glTF"
CT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
NC = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def read_glb(data):
    """(json dict, bin bytes or b'') from GLB bytes."""
    if data[:4] != GLB_MAGIC:
        raise ValueError("not a GLB")
    _, version, length = struct.unpack_from("<III", data, 0)
    if version != 2:
        raise ValueError(f"GLB version {version}")
    off, doc, bin_ = 12, None, b""
    while off + 8 <= min(length, len(data)):
        ln, kind = struct.unpack_from("<II", data, off)
        chunk = data[off + 8: off + 8 + ln]
        if kind == 0x4E4F534A and doc is None:
            doc = json.loads(chunk.rstrip(b" \x00").decode("utf-8"))
        elif kind == 0x004E4942 and not bin_:
            bin_ = bytes(chunk)
        off += 8 + ln + (4 - ln % 4) % 4
    if doc is None:
        raise ValueError("GLB without JSON chunk")
    return doc, bin_


def write_glb(doc, bin_):
    js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    js += b" " * ((4 - len(js) % 4) % 4)
    bin_ = bytes(bin_) + b"\x00" * ((4 - len(bin_) % 4) % 4)
    out = [struct.pack("<II", len(js), 0x4E4F534A), js]
    if bin_:
        out += [struct.pack("<II", len(bin_), 0x004E4942), bin_]
    body = b"".join(out)
    return struct.pack("<4sII", GLB_MAGIC, 2, 12 + len(body)) + body


def load_any(path):
    """(doc, bin) for a .glb/.vrm file, or a self-contained GLB built from a .gltf."""
    data = open(path, "rb").read()
    if data[:4] == GLB_MAGIC:
        return read_glb(data)
    return pack_gltf(json.loads(data.decode("utf-8-sig")), lambda uri: open(os.path.join(os.path.dirname(path), uri), "rb").read())


def _data_uri(uri):
    head, _, payload = uri.partition(",")
    return base64.b64decode(payload) if head.endswith(";base64") else payload.encode()


def pack_gltf(doc, read_uri):
    """Repack a glTF JSON whose buffers/images are URIs (read with read_uri(relpath) -> bytes)
    into (doc, bin) for one GLB: all buffers concatenated into buffer 0, images embedded as
    bufferViews. Images that cannot be read are dropped (with their textures' references)."""
    from urllib.parse import unquote

    def get(uri):
        if uri.startswith("data:"):
            return _data_uri(uri)
        return read_uri(unquote(uri))

    blob = bytearray()
    starts = []
    for b in doc.get("buffers", []):
        data = get(b["uri"]) if "uri" in b else b""
        while len(blob) % 8:
            blob.append(0)
        starts.append(len(blob))
        blob += data[: b.get("byteLength", len(data))]
    for v in doc.get("bufferViews", []):
        v["byteOffset"] = v.get("byteOffset", 0) + starts[v["buffer"]]
        v["buffer"] = 0
    keep_img = []
    for im in doc.get("images", []):
        if "uri" in im:
            try:
                data = get(im["uri"])
            except Exception:
                keep_img.append(False)
                continue
            uri = im.pop("uri")
            while len(blob) % 8:
                blob.append(0)
            doc.setdefault("bufferViews", []).append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
            blob += data
            im["bufferView"] = len(doc["bufferViews"]) - 1
            if "mimeType" not in im:
                im["mimeType"] = "image/jpeg" if uri.lower().endswith((".jpg", ".jpeg")) else "image/png"
        keep_img.append(True)
    if not all(keep_img):
        _drop_images(doc, keep_img)
    doc["buffers"] = [{"byteLength": len(blob)}] if blob else []
    return doc, bytes(blob)


def _drop_images(doc, keep):
    remap, imgs = {}, []
    for i, (im, k) in enumerate(zip(doc.get("images", []), keep)):
        if k:
            remap[i] = len(imgs)
            imgs.append(im)
    doc["images"] = imgs
    tex_ok = []
    for t in doc.get("textures", []):
        src = t.get("source")
        if src is not None and src not in remap:
            t.pop("source")
        elif src is not None:
            t["source"] = remap[src]
        tex_ok.append("source" in t or any(k for k in t.get("extensions", {})))
    # Materials keep their texture references; a texture without a source is legal glTF.


def accessor(doc, bin_, idx):
    """Accessor data as float64 array (n, ncomp), normalised ints scaled to [0,1]."""
    a = doc["accessors"][idx]
    n, nc = a["count"], NC[a["type"]]
    dt = np.dtype(CT[a["componentType"]])
    out = np.zeros((n, nc), dtype=np.float64)
    if "bufferView" in a:
        v = doc["bufferViews"][a["bufferView"]]
        stride = v.get("byteStride") or dt.itemsize * nc
        off = v.get("byteOffset", 0) + a.get("byteOffset", 0)
        if n:
            need = off + stride * (n - 1) + dt.itemsize * nc
            if need > len(bin_):
                raise ValueError(f"accessor {idx} past buffer end")
            raw = np.ndarray((n, nc), dtype=dt, buffer=bin_, offset=off, strides=(stride, dt.itemsize))
            out = raw.astype(np.float64)
    sp = a.get("sparse")
    if sp:
        iv, vv = sp["indices"], sp["values"]
        it = np.dtype(CT[iv["componentType"]])
        bi = doc["bufferViews"][iv["bufferView"]]
        ind = np.frombuffer(bin_, dtype=it, count=sp["count"], offset=bi.get("byteOffset", 0) + iv.get("byteOffset", 0))
        bv = doc["bufferViews"][vv["bufferView"]]
        val = np.frombuffer(bin_, dtype=dt, count=sp["count"] * nc, offset=bv.get("byteOffset", 0) + vv.get("byteOffset", 0)).reshape(-1, nc)
        out[ind.astype(np.int64)] = val
    if a.get("normalized") and dt.kind in "iu":
        out = out / float(np.iinfo(dt).max)
    return out


def node_local(n):
    if "matrix" in n:
        return np.array(n["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = n.get("rotation", [0, 0, 0, 1])
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r * np.array(n.get("scale", [1, 1, 1]))[None, :]
    m[:3, 3] = n.get("translation", [0, 0, 0])
    return m


def world_matrices(doc):
    nodes = doc.get("nodes", [])
    parent = {}
    for i, n in enumerate(nodes):
        for c in n.get("children", []):
            parent[c] = i
    world = {}

    def w(i, depth=0):
        if i not in world:
            if depth > len(nodes):
                raise ValueError("node cycle")
            m = node_local(nodes[i])
            world[i] = w(parent[i], depth + 1) @ m if i in parent else m
        return world[i]

    return [w(i) for i in range(len(nodes))], parent


def rig_stats(doc, bin_):
    """Facts about the skinning of one glTF: used joints (node ids), joint names, skinned
    vertex count, unweighted count, max raw weight-sum deviation, problems (list of str)."""
    nodes = doc.get("nodes", [])
    world, parent = world_matrices(doc)
    problems = []
    joints, skinned_v, unweighted, rigid_v, max_dev = [], 0, 0, 0, 0.0
    bind_pos = {}
    allpos = []
    for ni, n in enumerate(nodes):
        if "mesh" not in n:
            continue
        mesh = doc["meshes"][n["mesh"]]
        skin_i = n.get("skin")
        for p in mesh.get("primitives", []):
            at = p.get("attributes", {})
            if "POSITION" not in at or p.get("mode", 4) not in (4, 5, 6):
                continue
            pos = accessor(doc, bin_, at["POSITION"])
            if not np.isfinite(pos).all():
                problems.append("non-finite vertex positions")
                continue
            if skin_i is None or "JOINTS_0" not in at or "WEIGHTS_0" not in at:
                rigid_v += len(pos)
                allpos.append((world[ni] @ np.c_[pos, np.ones(len(pos))].T).T[:, :3])
                continue
            skin = doc["skins"][skin_i]
            sj = skin["joints"]
            ws, js = [], []
            k = 0
            while f"WEIGHTS_{k}" in at and f"JOINTS_{k}" in at:
                ws.append(accessor(doc, bin_, at[f"WEIGHTS_{k}"]))
                js.append(accessor(doc, bin_, at[f"JOINTS_{k}"]))
                k += 1
            w = np.concatenate(ws, axis=1)
            j = np.concatenate(js, axis=1)
            if not np.isfinite(w).all() or (w < -1e-6).any():
                problems.append("non-finite or negative weights")
                continue
            if ((j >= len(sj)) & (w > 0)).any():
                problems.append("joint index past skin joints")
                continue
            tot = w.sum(axis=1)
            unweighted += int((tot <= 1e-8).sum())
            ok = tot > 1e-8
            if ok.any():
                max_dev = max(max_dev, float(np.abs(tot[ok] - 1).max()))
                wn = w[ok] / tot[ok, None]
                if float(np.abs(wn.sum(axis=1) - 1).max()) > 1e-3:
                    problems.append("weights do not normalise")
            skinned_v += len(pos)
            for jj in sj:
                if jj not in joints:
                    joints.append(jj)
            ibm = accessor(doc, bin_, skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1) if "inverseBindMatrices" in skin else np.tile(np.eye(4), (len(sj), 1, 1))
            if len(ibm) < len(sj):
                problems.append("too few inverse bind matrices")
                continue
            if not np.isfinite(ibm).all():
                problems.append("non-finite inverse bind matrices")
                continue
            # vertices are in the mesh node's frame per glTF skinning: world = sum w * J_world * IBM * v
            # the bind pose joint is inverse(IBM) in the skinned mesh's frame
            for k2, jj in enumerate(sj):
                if jj in bind_pos:
                    continue
                d = np.linalg.det(ibm[k2])
                if not np.isfinite(d) or abs(d) < 1e-20:
                    continue
                bind_pos[jj] = np.linalg.inv(ibm[k2])[:3, 3]
            allpos.append(pos)
    names = [nodes[j].get("name") or f"node{j}" for j in joints]
    res = {"joints": joints, "names": names, "skinned_vertices": skinned_v, "unweighted": unweighted,
           "rigid_vertices": rigid_v, "max_weight_dev": max_dev, "problems": problems}
    # bind-pose sanity: finite, not all coincident, within a generous box around the mesh
    if joints:
        missing = [j for j in joints if j not in bind_pos]
        if missing:
            problems.append(f"{len(missing)} joints with singular bind matrices")
        if bind_pos:
            bp = np.array(list(bind_pos.values()))
            pts = np.concatenate(allpos) if allpos else bp
            lo, hi = pts.min(0), pts.max(0)
            diag = float(np.linalg.norm(hi - lo))
            res["diag"] = diag
            if not np.isfinite(bp).all():
                problems.append("non-finite bind pose")
            elif diag <= 0:
                problems.append("degenerate mesh")
            else:
                far = np.linalg.norm(bp - (lo + hi) / 2, axis=1).max() / diag
                res["bind_far"] = float(far)
                if far > 5:
                    problems.append(f"bind pose far from mesh ({far:.1f} diagonals)")
                if len(bp) >= 2 and float(np.linalg.norm(bp.max(0) - bp.min(0))) < 1e-6 * diag:
                    problems.append("all joints coincide")
    return res


def rig_problems(stats):
    """Why a rig is unusable for training ([] when usable)."""
    out = list(stats["problems"])
    if len(stats["joints"]) < 2:
        out.append(f"{len(stats['joints'])} joints (< 2)")
    if stats["skinned_vertices"] == 0:
        out.append("no skinned vertices")
    if stats["rigid_vertices"] > stats["skinned_vertices"]:
        out.append(f"most vertices outside skinned meshes ({stats['rigid_vertices']} rigid, {stats['skinned_vertices']} skinned)")
    if stats["unweighted"]:
        out.append(f"{stats['unweighted']} of {stats['skinned_vertices']} skinned vertices unweighted")
    return out


def renormalise_weights(doc, bin_):
    """Rewrite WEIGHTS_n of skinned primitives as float32 normalised per vertex when their
    sums stray from 1 by more than 1e-4. Returns (doc, bin, changed)."""
    blob = bytearray(bin_)
    changed = False
    done = {}
    for n in doc.get("nodes", []):
        if "mesh" not in n or "skin" not in n:
            continue
        for p in doc["meshes"][n["mesh"]].get("primitives", []):
            at = p.get("attributes", {})
            keys = []
            k = 0
            while f"WEIGHTS_{k}" in at and f"JOINTS_{k}" in at:
                keys.append(f"WEIGHTS_{k}")
                k += 1
            if not keys:
                continue
            sig = tuple(at[x] for x in keys)
            if sig in done:
                for x, new in zip(keys, done[sig]):
                    at[x] = new
                continue
            ws = [accessor(doc, bin_, at[x]) for x in keys]
            w = np.concatenate(ws, axis=1)
            tot = w.sum(axis=1)
            if not (np.abs(tot - 1) > 1e-4).any():
                done[sig] = sig
                continue
            safe = np.where(tot > 1e-8, tot, 1.0)
            w = w / safe[:, None]
            new = []
            for i, x in enumerate(keys):
                part = np.ascontiguousarray(w[:, 4 * i: 4 * i + 4], dtype=np.float32)
                while len(blob) % 4:
                    blob.append(0)
                doc.setdefault("bufferViews", []).append({"buffer": 0, "byteOffset": len(blob), "byteLength": part.nbytes})
                blob += part.tobytes()
                doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126,
                                         "count": len(part), "type": "VEC4"})
                new.append(len(doc["accessors"]) - 1)
                at[x] = new[-1]
            done[sig] = tuple(new)
            changed = True
    if changed:
        if not doc.get("buffers"):
            doc["buffers"] = [{}]
        doc["buffers"][0] = {k: v for k, v in doc["buffers"][0].items() if k != "uri"}
        doc["buffers"][0]["byteLength"] = len(blob)
    return doc, bytes(blob), changed
