"""Turns a [`Rig`] into a GLB: node hierarchy, skin, meshes, materials.

The displayed character is fixed (world space, Y-up, metres); the file's encoding of it
varies the way real exports do: an armature node or none, a 0.01/100 scale and a -90° X
rotation on it, joint nodes with or without their own rotations, one merged primitive or
many parts, unskinned accessories parented to bones. Whatever the encoding, each inverse
bind matrix is the exact inverse of its joint's world matrix, and the skinned vertices are
stored in world space, so every encoding displays the same model."""

from __future__ import annotations

import numpy as np

from . import shapes
from .glb import ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, GltfBuilder, quat_matrix
from .rig import Rig, perp, unit
from .skinning import candidates, part_weights, to_float32_normalized

LEVELS = [
    (4, 3, 1, 1),
    (5, 3, 1, 1),
    (6, 4, 1, 1),
    (8, 5, 2, 1),
    (10, 6, 2, 2),
    (12, 7, 3, 2),
    (16, 9, 4, 2),
    (20, 11, 5, 3),
    (24, 13, 6, 3),
    (32, 17, 8, 4),
    (40, 21, 10, 5),
]
MIN_VERTS, MAX_VERTS = 200, 8000


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """(x, y, z, w) unit quaternion of a rotation matrix, w >= 0."""
    t = np.trace(m)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return quat_matrix(q / np.linalg.norm(q))


def trs(t, r3, s: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = r3 * s
    m[:3, 3] = t
    return m


def _f32(x) -> list[float]:
    # Values go through float32 so the JSON holds exactly what a reader's f32 sees, and
    # the inverse bind matrices are computed from those same numbers.
    return [float(v) for v in np.asarray(x, dtype=np.float32)]


class Encoding:
    """How the file encodes the displayed rig."""

    def __init__(self, rng: np.random.Generator):
        r = rng.random()
        self.armature = r < 0.65
        self.arm_scale = 1.0
        self.arm_rot = np.eye(3)
        self.arm_name = str(rng.choice(["Armature", "Root", "RootNode", "Skeleton", "rig", "metarig", "Armature.001"]))
        if self.armature and rng.random() < 0.3:
            # ~20% of all files: unit or axis conversions left on the armature.
            kind = rng.choice(["cm_zup", "cm", "x100", "zup"], p=[0.4, 0.2, 0.15, 0.25])
            if kind in ("cm_zup", "cm"):
                self.arm_scale = 0.01
            elif kind == "x100":
                self.arm_scale = 100.0
            if kind in ("cm_zup", "zup"):
                self.arm_rot = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # -90° about X
        self.joint_rot = str(rng.choice(["none", "along", "random"], p=[0.5, 0.35, 0.15]))
        self.mesh_under_armature = self.armature and rng.random() < 0.15
        self.shuffle_nodes = rng.random() < 0.12
        self.shuffle_joints = rng.random() < 0.1
        self.skeleton_prop = rng.random() < 0.5
        self.joints_u8 = rng.random() < 0.6
        self.indices_u32 = rng.random() < 0.2
        self.flat_shading = rng.random() < 0.12
        self.layout = str(rng.choice(["merged", "by_group", "by_material", "per_part", "multi_node"],
                                     p=[0.3, 0.2, 0.15, 0.2, 0.15]))


def joint_world_rotations(rig: Rig, enc: Encoding, rng: np.random.Generator) -> list[np.ndarray]:
    out = []
    roll_hint = unit(rng.normal(size=3)) if rng.random() < 0.3 else np.array([1.0, 0.0, 0.0])
    for i in range(len(rig)):
        if enc.joint_rot == "none":
            out.append(enc.arm_rot.copy())
        elif enc.joint_rot == "along":
            # Blender's convention: each joint's local +Y runs along its bone.
            y = unit(rig.tails[i] - rig.heads[i])
            if not np.any(y):
                y = np.array([0.0, 1.0, 0.0])
            x = perp(y, roll_hint)
            z = np.cross(x, y)
            out.append(np.stack([x, y, z], 1))
        else:
            out.append(random_rotation(rng))
    return out


def pick_level(rig: Rig, target: int, ref_r: float, flat: bool = False) -> int:
    est = []
    for lv in range(len(LEVELS)):
        count = shapes.flat_vertex_estimate if flat else shapes.vertex_estimate
        est.append(sum(count(p, *part_res(p, lv, ref_r)) for p in rig.parts))
    best = 0
    for lv, e in enumerate(est):
        if e <= target:
            best = lv
    while best + 1 < len(LEVELS) and est[best] < MIN_VERTS:
        best += 1
    return best


def part_res(p, lv: int, ref_r: float):
    n, rings, k, sub = LEVELS[lv]
    # Small parts (fingers, toes) get fewer segments, as modellers give them.
    f = np.clip(np.sqrt(max(p.r0, p.r1) / max(ref_r, 1e-9)), 0.5, 1.0)
    return max(4, int(round(n * f))), max(3, int(round(rings * f))), k, sub


def build_geometry(rig: Rig, rng: np.random.Generator, enc: Encoding):
    """Per part: positions, normals, triangles, joints, weights (world space)."""
    radii = np.array([max(p.r0, p.r1) for p in rig.parts if p.kind != "sheet"] or [1.0])
    ref_r = float(np.percentile(radii, 85))
    hi = 3000 if rig.category == "robot_prop" else 7000
    target = int(np.exp(rng.uniform(np.log(300), np.log(hi))))
    lv = pick_level(rig, target, ref_r, enc.flat_shading)
    heads = np.array(rig.heads)
    tails = np.array(rig.tails)
    kids = rig.children()
    blend = rng.uniform(0.35, 1.0)
    out = []
    for p in rig.parts:
        pos, nrm, tris = shapes.build(p, *part_res(p, lv, ref_r))
        if enc.flat_shading and p.kind != "sheet":
            a, b, c = pos[tris[:, 0]], pos[tris[:, 1]], pos[tris[:, 2]]
            fn = np.cross(b - a, c - a)
            fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
            pos = np.stack([a, b, c], 1).reshape(-1, 3)
            nrm = np.repeat(fn, 3, axis=0)
            tris = np.arange(len(pos)).reshape(-1, 3)
            bad = np.linalg.norm(nrm, axis=1) < 0.5
            nrm[bad] = [0.0, 1.0, 0.0]
        cands = p.cands if p.cands is not None else candidates(p.bone, rig.parents, kids, rig.deform)
        width = max(0.5 * (p.r0 + p.r1), 1e-4) * blend
        j, w = part_weights(pos, p.bone, cands, heads, tails, width, p.rigid or rig.rigid)
        out.append((p, pos, nrm, tris, j, w))
    return out


def encode(rig: Rig, rng: np.random.Generator) -> tuple[bytes, dict]:
    rig.finalize()
    rig.check()
    enc = Encoding(rng)
    n = len(rig)
    W = joint_world_rotations(rig, enc, rng)
    s = enc.arm_scale if enc.armature else 1.0
    arm_t = np.zeros(3)
    G_arm = trs(arm_t, enc.arm_rot if enc.armature else np.eye(3), s)

    nodes: list[dict] = []
    arm_node = None
    if enc.armature:
        arm_node = 0
        node = {"name": enc.arm_name, "children": []}
        if s != 1.0:
            node["scale"] = [s, s, s]
        if not np.allclose(enc.arm_rot, np.eye(3)):
            node["rotation"] = _f32(quat_from_matrix(enc.arm_rot))
        nodes.append(node)
    joint_node = []
    G = []
    for i in range(n):
        p = rig.parents[i]
        if p >= 0:
            Wp, Pp, Gp = W[p], rig.heads[p], G[p]
        elif enc.armature:
            Wp, Pp, Gp = enc.arm_rot, arm_t, G_arm
        else:
            Wp, Pp, Gp = np.eye(3), np.zeros(3), np.eye(4)
        t = np.array(_f32(Wp.T @ (rig.heads[i] - Pp) / s))
        node = {"name": rig.names[i], "translation": [float(x) for x in t]}
        r_local = Wp.T @ W[i]
        if not np.allclose(r_local, np.eye(3), atol=1e-9):
            q = np.array(_f32(quat_from_matrix(r_local)), dtype=np.float64)
            node["rotation"] = [float(x) for x in q]
            r_exact = quat_matrix(q)
        else:
            r_exact = np.eye(3)
        # The world matrix from exactly the numbers written, so the IBM inverts what a
        # reader will compute, not what we meant.
        G.append(Gp @ trs(t, r_exact, 1.0))
        joint_node.append(len(nodes))
        nodes.append(node)
        parent_node = joint_node[p] if p >= 0 else arm_node
        if parent_node is not None:
            nodes[parent_node].setdefault("children", []).append(joint_node[i])

    ibm = np.array([np.linalg.inv(g) for g in G])
    ibm[:, 3, :] = [0.0, 0.0, 0.0, 1.0]

    order = np.arange(n)
    if enc.shuffle_joints:
        order = rng.permutation(n)
    slot = np.empty(n, dtype=np.int64)
    slot[order] = np.arange(n)

    geo = build_geometry(rig, rng, enc)
    gb = GltfBuilder()
    gb.json["asset"]["generator"] = "rigserve synth"

    # Materials: one colour per material slot, plus a few for multi-part layouts.
    n_mat = 1 + max([p.mat for p in rig.parts] + [0])
    mats = []
    base_h = rng.random()
    for k in range(max(n_mat, 4)):
        h = (base_h + k * rng.uniform(0.1, 0.4)) % 1.0
        mats.append(_material(rng, h, f"mat_{k}"))

    skinned = [g for g in geo if not g[0].node]
    attached = [g for g in geo if g[0].node]
    groups = _group(skinned, enc, rng)
    mesh_nodes = []
    meshes = []
    used_mats: dict[int, int] = {}

    def mat_index(k: int) -> int:
        if k not in used_mats:
            used_mats[k] = len(used_mats)
        return used_mats[k]

    mesh_names = ["Body", "Mesh", "Object_0", "body_geo", "Character", rig.kind or "Model"]
    for gi, prim_lists in enumerate(groups):
        prims = []
        for pl in prim_lists:
            pos = np.concatenate([g[1] for g in pl]).astype(np.float32)
            nrm = np.concatenate([g[2] for g in pl])
            nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
            offs = np.cumsum([0] + [len(g[1]) for g in pl])
            tris = np.concatenate([g[3] + o for g, o in zip(pl, offs)])
            jnt = slot[np.concatenate([g[4] for g in pl])]
            wts = np.concatenate([g[5] for g in pl])
            jnt[wts == 0.0] = 0
            w32 = to_float32_normalized(wts)
            jdt = np.uint8 if (enc.joints_u8 and n <= 256) else np.uint16
            idt = np.uint32 if (enc.indices_u32 or len(pos) > 65535) else np.uint16
            attrs = {
                "POSITION": gb.add_accessor(pos, "VEC3", ARRAY_BUFFER, minmax=True),
                "NORMAL": gb.add_accessor(nrm, "VEC3", ARRAY_BUFFER),
                "JOINTS_0": gb.add_accessor(jnt.astype(jdt), "VEC4", ARRAY_BUFFER),
                "WEIGHTS_0": gb.add_accessor(w32, "VEC4", ARRAY_BUFFER),
            }
            prim = {
                "attributes": attrs,
                "indices": gb.add_accessor(tris.astype(idt).reshape(-1), "SCALAR", ELEMENT_ARRAY_BUFFER),
                "material": mat_index(_dominant_mat(pl, enc)),
            }
            prims.append(prim)
        name = mesh_names[int(rng.integers(len(mesh_names)))] + (f"_{gi}" if len(groups) > 1 else "")
        meshes.append({"name": name, "primitives": prims})
        mesh_nodes.append(len(nodes))
        nodes.append({"name": name, "mesh": len(meshes) - 1, "skin": 0})

    # Unskinned accessories: a node under the bone, vertices in that node's frame.
    prop_count: dict[int, int] = {}
    for p, pos, nrm, tris, _, _ in attached:
        j = p.bone
        center = pos.mean(0)
        t_local = W[j].T @ (center - rig.heads[j]) / s
        t_local = np.array(_f32(t_local))
        M = G[j] @ trs(t_local, np.eye(3), 1.0)
        Minv = np.linalg.inv(M)
        lp = (pos @ Minv[:3, :3].T + Minv[:3, 3]).astype(np.float32)
        ln = nrm @ M[:3, :3]
        ln = (ln / np.linalg.norm(ln, axis=1, keepdims=True)).astype(np.float32)
        idt = np.uint32 if (enc.indices_u32 or len(lp) > 65535) else np.uint16
        prim = {
            "attributes": {
                "POSITION": gb.add_accessor(lp, "VEC3", ARRAY_BUFFER, minmax=True),
                "NORMAL": gb.add_accessor(ln, "VEC3", ARRAY_BUFFER),
            },
            "indices": gb.add_accessor(tris.astype(idt).reshape(-1), "SCALAR", ELEMENT_ARRAY_BUFFER),
            "material": mat_index(p.mat if p.mat < len(mats) else 0),
        }
        meshes.append({"name": f"acc_{len(meshes)}", "primitives": [prim]})
        acc_node = len(nodes)
        prop_count[j] = prop_count.get(j, 0) + 1
        suffix = "" if prop_count[j] == 1 else f"_{prop_count[j]}"
        nodes.append({"name": f"{rig.names[j]}_prop{suffix}", "mesh": len(meshes) - 1, "translation": [float(x) for x in t_local]})
        nodes[joint_node[j]].setdefault("children", []).append(acc_node)

    roots = []
    if enc.armature:
        roots.append(arm_node)
    else:
        roots.extend(joint_node[i] for i in range(n) if rig.parents[i] < 0)
    for m in mesh_nodes:
        if enc.mesh_under_armature:
            nodes[arm_node]["children"].append(m)
        else:
            roots.append(m)

    skin = {
        "joints": [joint_node[int(b)] for b in order],
        "inverseBindMatrices": gb.add_accessor(
            np.ascontiguousarray(ibm[order].transpose(0, 2, 1)).astype(np.float32), "MAT4"
        ),
    }
    root_joints = [i for i in range(n) if rig.parents[i] < 0]
    if enc.skeleton_prop and len(root_joints) == 1:
        skin["skeleton"] = joint_node[root_joints[0]]
    skin["name"] = enc.arm_name if enc.armature else "skin"

    if enc.shuffle_nodes:
        perm = rng.permutation(len(nodes))  # perm[new] = old
        new_of = np.empty(len(nodes), dtype=np.int64)
        new_of[perm] = np.arange(len(nodes))
        nodes = [nodes[int(o)] for o in perm]
        for nd in nodes:
            if "children" in nd:
                nd["children"] = [int(new_of[c]) for c in nd["children"]]
        roots = [int(new_of[r]) for r in roots]
        skin["joints"] = [int(new_of[j]) for j in skin["joints"]]
        if "skeleton" in skin:
            skin["skeleton"] = int(new_of[skin["skeleton"]])

    for nd in nodes:
        if "children" in nd and not nd["children"]:
            del nd["children"]
    inv_used = sorted(used_mats.items(), key=lambda kv: kv[1])
    gb.json.update(
        {
            "scene": 0,
            "scenes": [{"name": "Scene", "nodes": roots}],
            "nodes": nodes,
            "meshes": meshes,
            "skins": [skin],
            "materials": [mats[k] for k, _ in inv_used],
        }
    )
    data = gb.to_bytes()
    info = {
        "bones": n,
        "vertices": int(sum(len(g[1]) for g in geo)),
        "primitives": sum(len(m["primitives"]) for m in meshes),
        "kind": rig.kind,
    }
    return data, info


def _material(rng, h: float, name: str) -> dict:
    s = rng.uniform(0.2, 0.9)
    v = rng.uniform(0.35, 1.0)
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    rgb = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]
    return {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [round(float(c), 4) for c in rgb] + [1.0],
            "metallicFactor": round(float(rng.choice([0.0, 0.0, 0.3, 1.0])), 2),
            "roughnessFactor": round(float(rng.uniform(0.3, 1.0)), 3),
        },
    }


def _dominant_mat(pl, enc) -> int:
    mats = [g[0].mat for g in pl]
    return max(set(mats), key=mats.count)


def _group(geo, enc: Encoding, rng):
    """Meshes (outer list) of primitives (inner lists) of parts."""
    if not geo:
        raise ValueError("a rig needs at least one skinned part")
    if enc.layout == "merged":
        return [[geo]]
    if enc.layout in ("by_group", "by_material"):
        key = (lambda g: g[0].group) if enc.layout == "by_group" else (lambda g: g[0].mat)
        buckets: dict = {}
        for g in geo:
            buckets.setdefault(key(g), []).append(g)
        return [list(buckets.values())]
    if enc.layout == "per_part":
        return [[[g] for g in geo]]
    # multi_node: contiguous runs of parts in separate mesh nodes sharing the skin.
    k = int(min(len(geo), rng.integers(2, 5)))
    cuts = np.array_split(np.arange(len(geo)), k)
    return [[[geo[i] for i in c]] for c in cuts if len(c)]
