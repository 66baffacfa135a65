#!/usr/bin/env python3
"""Baseline skin weights: Blender's "automatic weights" (bone heat) on the artist skeleton.

For each data-set file, the artist's skeleton is kept in its bind pose, the artist's
weights are thrown away, and Blender's automatic weights re-skin the bare mesh. The
result is written as a GLB with the same name, so that

    rigserve eval --dataset DATASET --split dev --pred OUT --out report.json

scores Blender with the code that scores rigserve (bones are matched by name and
vertices by nearest rest position, so names and the world frame must survive).

Usage:
    python3 bench/blender_heat.py --dataset ../shared/rigs [--split dev] --out DIR
                                  [--files a.glb,b.glb] [--deform-only-weighted] [--no-weld]
    python3 bench/blender_heat.py --time-mesh FILE [--subdivide CUTS] [--repeat N]

The first form writes DIR/<file>.glb and DIR/timings.json:
    {file: {"seconds", "vertices", "bones", "heat_failed", ...diagnostics}}
`seconds` is the wall clock of the automatic-weights step alone (import and export
excluded); `vertices` counts the welded mesh bone heat ran on. timings.json is updated,
not replaced, so `--files` reruns keep other rows.

`--time-mesh FILE` takes one rigged GLB, prepares it the same way and only times
automatic weights on it, printing one JSON object on stdout.

What is Blender's and what is not: every joint is a deforming bone (the file does not
say which bones the artist let deform), coincident vertices are merged before bone heat
(on meshes split along seams, as imported from glTF, it fails), and the export's
`neutral_bone` for vertices bone heat left unweighted is dropped again (they stay at
rest, as in Blender). See bench/README.md.

Needs Blender as a Python module (`pip install bpy==5.0.1`).
"""

import argparse
import contextlib
import json
import math
import os
import struct
import sys
import tempfile
import time

# bpy reports a missing sound device on stdout at import; keep stdout for results.
_stdout = os.dup(1)
os.dup2(2, 1)
try:
    import bpy
    import bmesh  # importable only once bpy is loaded
    from mathutils import Matrix, Quaternion, Vector, kdtree
finally:
    os.dup2(_stdout, 1)
    os.close(_stdout)

# Blender's glTF importer maps glTF (x, y, z) to Blender (x, -z, y).
TO_BLENDER = Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))
TO_GLTF = TO_BLENDER.inverted()

HEAT_FAILED = "Bone Heat Weighting: failed to find solution"

# --------------------------------------------------------------------------------------
# Reading the GLB ourselves: Blender's importer guesses the bind frame of a skin from the
# skinned mesh node, while rigserve maps it through the skin's root joint (see
# src/mesh/scene.rs, skin_to_world). Where the file was saved mid-pose the two differ by
# a rigid motion, and rigserve eval compares in rigserve's frame.

_COMPONENTS = {5120: "b", 5121: "B", 5122: "h", 5123: "H", 5125: "I", 5126: "f"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


class Glb:
    def __init__(self, path):
        with open(path, "rb") as f:
            data = f.read()
        magic, _version, _length = struct.unpack_from("<III", data, 0)
        if magic != 0x46546C67:
            raise ValueError(f"{path}: not a GLB")
        offset, self.json, self.bin = 12, None, b""
        while offset + 8 <= len(data):
            size, kind = struct.unpack_from("<II", data, offset)
            chunk = data[offset + 8 : offset + 8 + size]
            if kind == 0x4E4F534A:
                self.json = json.loads(chunk)
            elif kind == 0x004E4942:
                self.bin = chunk
            offset += 8 + size
        self.nodes = self.json.get("nodes", [])
        self.parent = {}
        for i, n in enumerate(self.nodes):
            for c in n.get("children", []):
                self.parent[c] = i
        self._world = {}

    def accessor(self, index):
        """Rows of floats (components as stored; normalised integers are not rescaled)."""
        a = self.json["accessors"][index]
        if "sparse" in a:
            raise ValueError("sparse accessors are not read")
        fmt = _COMPONENTS[a["componentType"]]
        width = _WIDTH[a["type"]]
        count = a["count"]
        if "bufferView" not in a:
            return [[0.0] * width for _ in range(count)]
        view = self.json["bufferViews"][a["bufferView"]]
        if view.get("buffer", 0) != 0:
            raise ValueError("only the GLB's own buffer is read")
        start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
        item = struct.calcsize("<" + fmt * width)
        stride = view.get("byteStride") or item
        rows = struct.Struct("<" + fmt * width)
        return [list(rows.unpack_from(self.bin, start + k * stride)) for k in range(count)]

    def local(self, i):
        n = self.nodes[i]
        if "matrix" in n:
            m = n["matrix"]
            return Matrix([[m[c * 4 + r] for c in range(4)] for r in range(4)])
        x, y, z, w = n.get("rotation", [0, 0, 0, 1])
        rot = Quaternion((w, x, y, z)).to_matrix().to_4x4()
        s = n.get("scale", [1, 1, 1])
        scale = Matrix.Diagonal((s[0], s[1], s[2], 1.0))
        return Matrix.Translation(n.get("translation", [0, 0, 0])) @ rot @ scale

    def world(self, i):
        if i not in self._world:
            chain, j = [], i
            while j is not None and j not in self._world:
                chain.append(j)
                j = self.parent.get(j)
            m = self._world[j] if j is not None else Matrix.Identity(4)
            for k in reversed(chain):
                m = m @ self.local(k)
                self._world[k] = m
        return self._world[i]

    def inverse_binds(self, skin):
        s = self.json["skins"][skin]
        if "inverseBindMatrices" not in s:
            return [Matrix.Identity(4) for _ in s["joints"]]
        return [
            Matrix([[m[c * 4 + r] for c in range(4)] for r in range(4)])
            for m in self.accessor(s["inverseBindMatrices"])[: len(s["joints"])]
        ]

    def skin_to_world(self, skin):
        """rigserve's bind frame of a skin: root joint's world times its inverse bind."""
        joints = self.json["skins"][skin]["joints"]
        inside = set(joints)

        def enclosed(j):
            k = self.parent.get(j)
            while k is not None:
                if k in inside:
                    return True
                k = self.parent.get(k)
            return False

        ibms = self.inverse_binds(skin)
        for k, j in enumerate(joints):
            if not enclosed(j):
                m = self.world(j) @ ibms[k]
                if all(math.isfinite(v) for row in m for v in row) and abs(m.determinant()) > 1e-20:
                    return m
                break
        return Matrix.Identity(4)

    def skinned_parts(self):
        """(node, primitive, skin) for skinned triangle primitives, as rigserve merges them."""
        meshes = self.json.get("meshes", [])
        for i, n in enumerate(self.nodes):
            if "mesh" not in n or "skin" not in n:
                continue
            for prim in meshes[n["mesh"]]["primitives"]:
                if prim.get("mode", 4) in (4, 5, 6) and "JOINTS_0" in prim["attributes"]:
                    yield i, prim, n["skin"]

    def ground_truth(self):
        """rigserve's view of the rig: bind-pose joint matrices (glTF world) by joint node
        (first skin wins where skins share joints), rigserve's unique joint names, and
        each skinned node's vertex positions in the same frame."""
        used = sorted({s for _, _, s in self.skinned_parts()})
        joints, frames = {}, {}
        for s in used:
            frames[s] = self.skin_to_world(s)
            skin = self.json["skins"][s]
            for j, ibm in zip(skin["joints"], self.inverse_binds(s)):
                if j not in joints:
                    joints[j] = frames[s] @ ibm.inverted_safe()
        positions, weighted = {}, {}
        for node, prim, s in self.skinned_parts():
            frame = frames[s]
            rows = self.accessor(prim["attributes"]["POSITION"])
            positions.setdefault(node, []).extend(frame @ Vector(p) for p in rows)
            has = [False] * len(rows)
            for set_ in range(8):
                if f"WEIGHTS_{set_}" not in prim["attributes"]:
                    break
                for i, w in enumerate(self.accessor(prim["attributes"][f"WEIGHTS_{set_}"])):
                    has[i] = has[i] or any(x > 0 and math.isfinite(x) for x in w)
            weighted.setdefault(node, []).extend(has)
        return joints, self.unique_names(list(joints)), positions, weighted

    def unique_names(self, order):
        """Joint names as rigserve gives them (src/rig/groundtruth.rs): depth first from
        the roots, a repeated name getting `.1`, `.2`, ... in that order."""
        inside = set(order)
        parent = {}
        for j in order:
            k = self.parent.get(j)
            while k is not None and k not in inside:
                k = self.parent.get(k)
            parent[j] = k
        kids = {}
        for j in order:
            if parent[j] is not None:
                kids.setdefault(parent[j], []).append(j)
        stack = [j for j in reversed(order) if parent[j] is None]
        names, seen = {}, {}
        while stack:
            j = stack.pop()
            base = self.nodes[j].get("name") or f"joint_{j}"
            count = seen.get(base, 0)
            names[j] = base if count == 0 else f"{base}.{count}"
            seen[base] = count + 1
            stack.extend(reversed(kids.get(j, [])))
        return names

    def write_in_bind_pose(self, path, joints, names):
        """Writes a copy whose joint nodes stand in their bind pose, carry rigserve's
        joint names (so that bones of two armatures cannot share one), and has no
        animations.

        Blender's importer takes the root joint's place from its node and the rest from
        the inverse bind matrices, and re-poses the mesh by the artist's weights to fit;
        in a file saved mid-pose that moves bones and vertices away from rigserve's bind
        frame. A file saved in its bind pose is imported as is."""
        doc = json.loads(json.dumps(self.json))
        doc.pop("animations", None)
        nodes = doc.get("nodes", [])
        new_world = {}

        def world(i):
            if i not in new_world:
                p = self.parent.get(i)
                above = world(p) if p is not None else Matrix.Identity(4)
                new_world[i] = joints[i] if i in joints else above @ self.local(i)
            return new_world[i]

        for i in joints:
            p = self.parent.get(i)
            above = world(p) if p is not None else Matrix.Identity(4)
            if abs(above.determinant()) < 1e-20:
                continue
            local = above.inverted() @ world(i)
            nodes[i]["name"] = names[i]
            for key in ("translation", "rotation", "scale"):
                nodes[i].pop(key, None)
            nodes[i]["matrix"] = [local[r][c] for c in range(4) for r in range(4)]
        write_glb(path, doc, self.bin)

    def strip_neutral_bone(self, path):
        """Drops the joint Blender's exporter adds for vertices without weights.

        glTF wants every skinned vertex weighted, so the exporter binds vertices that bone
        heat left unweighted to an extra `neutral_bone` at the origin. eval would count it
        as a wrong joint and a wrong bone; in Blender those vertices simply stay at rest,
        which is what no weights at all mean to eval. Returns whether the file changed."""
        doc, binary = self.json, bytearray(self.bin)
        done = set()
        changed = False
        for si, skin in enumerate(doc.get("skins", [])):
            extra = [k for k, j in enumerate(skin["joints"]) if self.nodes[j].get("name") == "neutral_bone"]
            if not extra:
                continue
            (k,) = extra
            node = skin["joints"].pop(k)
            for n in self.nodes:
                if node in n.get("children", []):
                    n["children"].remove(node)
                    if not n["children"]:
                        del n["children"]
            if "inverseBindMatrices" in skin:
                acc = doc["accessors"][skin["inverseBindMatrices"]]
                if k != acc["count"] - 1:
                    raise ValueError("neutral_bone is not the last joint")
                acc["count"] -= 1
            for n in self.nodes:
                if n.get("skin") != si or "mesh" not in n:
                    continue
                for prim in doc["meshes"][n["mesh"]]["primitives"]:
                    for set_ in range(8):
                        ja = prim["attributes"].get(f"JOINTS_{set_}")
                        wa = prim["attributes"].get(f"WEIGHTS_{set_}")
                        if ja is None or wa is None or (ja, wa) in done:
                            continue
                        done.add((ja, wa))
                        self._unbind(binary, ja, wa, k)
            changed = True
        if changed:
            write_glb(path, doc, bytes(binary))
        return changed

    def _unbind(self, binary, ja, wa, k):
        """Zeroes the weights on joint `k` in place (k is the skin's last joint, so no
        other joint index moves)."""
        places = []
        for index in (ja, wa):
            a = self.json["accessors"][index]
            view = self.json["bufferViews"][a["bufferView"]]
            fmt = _COMPONENTS[a["componentType"]]
            size = struct.calcsize("<" + fmt)
            start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
            places.append((fmt, size, start, view.get("byteStride") or 4 * size, a["count"]))
        (jf, js, j0, jstride, count), (wf, ws, w0, wstride, _) = places
        for v in range(count):
            for c in range(4):
                (joint,) = struct.unpack_from("<" + jf, binary, j0 + v * jstride + c * js)
                if joint == k:
                    struct.pack_into("<" + jf, binary, j0 + v * jstride + c * js, 0)
                    struct.pack_into("<" + wf, binary, w0 + v * wstride + c * ws, 0)


def write_glb(path, doc, binary):
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = binary + b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if binary:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    with open(path, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks)


# --------------------------------------------------------------------------------------
# Blender side.


@contextlib.contextmanager
def captured_output():
    """Blender prints operator reports (the heat failure among them) from C, so Python's
    sys.stdout never sees them: catch file descriptors 1 and 2 instead."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 1)
        os.dup2(tmp.fileno(), 2)
        box = {"text": ""}
        try:
            yield box
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            tmp.seek(0)
            box["text"] = tmp.read().decode("utf-8", "replace")
            sys.stderr.write(box["text"])


def import_glb(path):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with captured_output():
        # No bone display shape: it is an extra icosphere mesh that is not in the file.
        bpy.ops.import_scene.gltf(filepath=path, disable_bone_shape=True)


def owning_armature(obj, armatures):
    for mod in obj.modifiers:
        if mod.type == "ARMATURE" and mod.object in armatures:
            return mod.object
    p = obj.parent
    while p is not None:
        if p in armatures:
            return p
        p = p.parent
    return None


def frame_correction(arm, truth, root_names):
    """Rigid map (glTF world) from Blender's guessed bind frame to rigserve's.

    With the default bone heuristic the importer keeps each joint's axes as the bone's,
    so a bone's world matrix is the joint's bind matrix in Blender's frame, and the
    difference to rigserve's bind matrix of the same joint is the frame change."""
    names = [b.name for b in arm.data.bones if b.name in truth]
    if not names:
        return Matrix.Identity(4)
    pick = next((n for n in root_names if n in names), names[0])
    blender = TO_GLTF @ arm.matrix_world @ arm.data.bones[pick].matrix_local
    return truth[pick] @ blender.inverted_safe()


def select_only(objects, active):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in objects:
        o.select_set(True)
    bpy.context.view_layer.objects.active = active


def prepare(path, deform_only_weighted=False, weld=True, subdivide=0):
    """Imports `path` and leaves each armature in its bind pose (rigserve's frame, the
    artist's joint places) with its bare meshes beside it. Returns (pairs, diagnostics):
    pairs is [(armature, [meshes])]."""
    glb = Glb(path)
    joints, names, gt_by_node, weighted_by_node = glb.ground_truth()
    truth = {names[j]: m for j, m in joints.items()}
    gt_positions = [p for ps in gt_by_node.values() for p in ps]
    root_names = []
    for s in sorted({s for _, _, s in glb.skinned_parts()}):
        skin_joints = glb.json["skins"][s]["joints"]
        inside = set(skin_joints)
        for j in skin_joints:
            k = glb.parent.get(j)
            while k is not None and k not in inside:
                k = glb.parent.get(k)
            if k is None:
                root_names.append(names[j])
                break

    with tempfile.TemporaryDirectory() as tmp:
        posed = os.path.join(tmp, "bind_pose.glb")
        glb.write_in_bind_pose(posed, joints, names)
        import_glb(posed)
    scene_objects = list(bpy.context.scene.objects)
    armatures = [o for o in scene_objects if o.type == "ARMATURE"]
    if not armatures:
        raise RuntimeError("no armature was imported")
    meshes = [o for o in scene_objects if o.type == "MESH"]
    owner = {m: owning_armature(m, armatures) for m in meshes}
    # Vertex groups the artist weighted: only read with --deform-only-weighted.
    weighted_bones = set()
    for m in meshes:
        names = {g.index: g.name for g in m.vertex_groups}
        for v in m.data.vertices:
            for g in v.groups:
                if g.weight > 0 and g.group in names:
                    weighted_bones.add(names[g.group])

    # Unparent everything first, while accessories still sit where the file shows them.
    bpy.context.view_layer.update()
    worlds = {o: o.matrix_world.copy() for o in scene_objects}
    for o in scene_objects:
        o.parent = None
    for o in scene_objects:
        o.matrix_world = worlds[o]
    for o in scene_objects:
        if o.type not in ("MESH", "ARMATURE"):
            bpy.data.objects.remove(o, do_unlink=True)
    for o in list(bpy.context.scene.objects):
        # Actions would drive the pose again on the next depsgraph update.
        o.animation_data_clear()
        if o.type == "MESH" and o.data.shape_keys is not None:
            o.data.shape_keys.animation_data_clear()

    diag = {"armatures": len(armatures), "bind_frame_shift": 0.0}
    for arm in armatures:
        for pb in arm.pose.bones:
            for c in list(pb.constraints):
                pb.constraints.remove(c)
            pb.location = (0, 0, 0)
            pb.rotation_quaternion = (1, 0, 0, 0)
            pb.rotation_euler = (0, 0, 0)
            pb.scale = (1, 1, 1)
        arm.data.pose_position = "REST"
        fix = TO_BLENDER @ frame_correction(arm, truth, root_names) @ TO_GLTF
        shift = max(abs(fix[r][c] - (r == c)) for r in range(4) for c in range(4))
        diag["bind_frame_shift"] = max(diag["bind_frame_shift"], shift)
        arm.matrix_world = fix @ arm.matrix_world
        for m, a in owner.items():
            if a is arm:
                m.matrix_world = fix @ m.matrix_world
    bpy.context.view_layer.update()

    # Bare meshes: no artist weights, no armature, transforms baked into the vertices.
    for m in meshes:
        for mod in [mod for mod in m.modifiers if mod.type == "ARMATURE"]:
            m.modifiers.remove(mod)
        m.vertex_groups.clear()
        if m.data.users > 1:
            m.data = m.data.copy()
    if meshes:
        select_only(meshes, meshes[0])
        bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    size = bounds_diagonal(gt_positions) or 1.0
    diag["vertices_moved_to_file"] = restore_positions(meshes, gt_by_node, weighted_by_node, 1e-4 * size)
    diag["imported_vertices"] = sum(len(m.data.vertices) for m in meshes)
    if weld:
        # The importer splits vertices along UV and normal seams; bone heat diffuses over
        # the mesh's edges, and on a mesh cut into loose faces it fails outright. Merging
        # coincident vertices keeps every position, so eval's nearest-vertex matching
        # is unaffected.
        for m in meshes:
            bm = bmesh.new()
            bm.from_mesh(m.data)
            bmesh.ops.remove_doubles(bm, verts=bm.verts, dist=1e-5 * size)
            bm.to_mesh(m.data)
            bm.free()
    if subdivide:
        # Timing only: a denser copy of a real mesh, to time bone heat at a given size.
        for m in meshes:
            bm = bmesh.new()
            bm.from_mesh(m.data)
            bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=subdivide, use_grid_fill=True)
            bm.to_mesh(m.data)
            bm.free()

    # Joint places: after the frame change the heads already agree with rigserve's to
    # float precision (bind_error_before_snap says how well); setting them exactly keeps
    # the skeleton metrics at zero, so that eval compares the weights alone.
    worst = 0.0
    bones = 0
    removed = []
    for arm in armatures:
        select_only([arm], arm)
        bpy.ops.object.mode_set(mode="EDIT")
        to_local = arm.matrix_world.inverted_safe() @ TO_BLENDER
        for eb in arm.data.edit_bones:
            eb.use_connect = False
        # The importer also makes bones of plain nodes between joints; rigserve skips
        # them (a joint's parent is its nearest joint ancestor), and so must the export.
        for eb in [eb for eb in arm.data.edit_bones if eb.name not in truth]:
            removed.append(eb.name)
            for child in eb.children:
                child.parent = eb.parent
            arm.data.edit_bones.remove(eb)
        for eb in arm.data.edit_bones:
            target = to_local @ truth[eb.name].to_translation()
            delta = target - eb.head
            worst = max(worst, (arm.matrix_world.to_3x3() @ delta).length)
            eb.head += delta
            eb.tail += delta
        bpy.ops.object.mode_set(mode="OBJECT")
        if deform_only_weighted:
            for b in arm.data.bones:
                b.use_deform = b.name in weighted_bones
        bones += sum(b.use_deform for b in arm.data.bones)
    diag["bind_error_before_snap"] = worst / size
    diag["missing_joints"] = sorted(set(truth) - {b.name for a in armatures for b in a.data.bones})
    diag["removed_bones"] = sorted(removed)

    # The bare meshes must lie where rigserve put the artist's vertices.
    diag["vertex_error"] = vertex_error(meshes, gt_positions) / size

    biggest = max(armatures, key=lambda a: len(a.data.bones))
    pairs = []
    for arm in armatures:
        mine = [m for m in meshes if (owner[m] or biggest) is arm]
        if mine:
            pairs.append((arm, mine))
    diag["bones"] = bones
    return pairs, diag


def restore_positions(meshes, gt_by_node, weighted_by_node, tol):
    """Puts back the file's bind-pose vertex positions where the importer moved some.

    The importer re-poses skinned vertices by the artist's weights to fit the bind pose
    it chose; vertices without usable weights (none, NaN) land elsewhere, and may be
    many (a whole garment). Blender keeps the file's vertex order (no merging on
    import), so a mesh whose weighted vertices all sit on one skinned node's vertices,
    index for index, takes that node's positions. Returns how many vertices moved."""
    moved = 0
    free = dict(gt_by_node)
    for m in meshes:
        n = len(m.data.vertices)
        for node, gt in list(free.items()):
            if len(gt) != n:
                continue
            here = [TO_GLTF @ m.matrix_world @ v.co for v in m.data.vertices]
            off = [i for i, (a, b) in enumerate(zip(here, gt)) if (a - b).length > tol]
            if any(weighted_by_node[node][i] for i in off):
                continue
            to_local = m.matrix_world.inverted_safe() @ TO_BLENDER
            for i in off:
                m.data.vertices[i].co = to_local @ gt[i]
            moved += len(off)
            del free[node]
            break
    return moved


def bounds_diagonal(points):
    if not points:
        return 0.0
    lo = Vector([min(p[i] for p in points) for i in range(3)])
    hi = Vector([max(p[i] for p in points) for i in range(3)])
    return (hi - lo).length


def vertex_error(meshes, gt_positions):
    """Farthest distance (glTF frame) from a ground-truth vertex to a Blender vertex."""
    verts = [TO_GLTF @ m.matrix_world @ v.co for m in meshes for v in m.data.vertices]
    if not verts or not gt_positions:
        return float("nan")
    tree = kdtree.KDTree(len(verts))
    for i, v in enumerate(verts):
        tree.insert(v, i)
    tree.balance()
    return max(tree.find(p)[2] for p in gt_positions)


def automatic_weights(pairs):
    """Bone heat for every (armature, meshes) pair; returns (seconds, failed, log)."""
    seconds, failed, log = 0.0, False, ""
    for arm, meshes in pairs:
        select_only(meshes, arm)
        with captured_output() as out:
            t0 = time.perf_counter()
            bpy.ops.object.parent_set(type="ARMATURE_AUTO")
            seconds += time.perf_counter() - t0
        failed |= HEAT_FAILED in out["text"]
        log += out["text"]
    return seconds, failed, log


def unweighted_vertices(pairs):
    count = 0
    for _, meshes in pairs:
        for m in meshes:
            count += sum(1 for v in m.data.vertices if not any(g.weight > 0 for g in v.groups))
    return count


def export_glb(path):
    with captured_output():
        bpy.ops.export_scene.gltf(
            filepath=path,
            export_format="GLB",
            export_yup=True,
            export_skins=True,
            export_animations=False,
            export_morph=False,
            export_materials="NONE",
            export_apply=False,
            export_rest_position_armature=True,
            # All bones, deform or not: they are the artist's joints and eval matches
            # them by name.
            export_def_bones=False,
            export_influence_nb=4,
        )


def rig_file(src, dst, deform_only_weighted=False, weld=True):
    pairs, diag = prepare(src, deform_only_weighted, weld)
    seconds, failed, _ = automatic_weights(pairs)
    row = {
        "seconds": round(seconds, 4),
        "vertices": sum(len(m.data.vertices) for _, ms in pairs for m in ms),
        "bones": diag.pop("bones"),
        "heat_failed": failed,
        "unweighted_vertices": unweighted_vertices(pairs),
    }
    row.update(diag)
    export_glb(dst)
    row["neutral_bone_removed"] = Glb(dst).strip_neutral_bone(dst)
    return row


def read_manifest(dataset, split):
    with open(os.path.join(dataset, "manifest.tsv"), encoding="utf-8") as f:
        lines = [l.rstrip("\n") for l in f if l.strip()]
    header = [h.strip() for h in lines[0].split("\t")]
    fcol, scol = header.index("file"), header.index("split") if "split" in header else None
    rows = []
    for line in lines[1:]:
        v = line.split("\t")
        if split is None or (scol is not None and v[scol].strip() == split):
            rows.append(v[fcol].strip())
    return rows


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", help="folder holding manifest.tsv and the GLBs")
    ap.add_argument("--split", help="only rows of this split (e.g. dev)")
    ap.add_argument("--out", help="folder for the rigged GLBs and timings.json")
    ap.add_argument("--files", help="comma-separated file names: only these rows")
    ap.add_argument(
        "--deform-only-weighted",
        action="store_true",
        help="mark bones the artist gave no weight as non-deforming (uses the artist's "
        "weights, so not a blind baseline; shows what knowing the deform set is worth)",
    )
    ap.add_argument(
        "--no-weld",
        action="store_true",
        help="run bone heat on the mesh as imported (split along seams; heat often fails)",
    )
    ap.add_argument("--time-mesh", metavar="FILE", help="only time automatic weights on one rigged GLB")
    ap.add_argument("--repeat", type=int, default=1, help="--time-mesh: how many runs")
    ap.add_argument(
        "--subdivide",
        type=int,
        default=0,
        metavar="CUTS",
        help="--time-mesh: cut every edge CUTS times first (1 cut gives about 4x the vertices)",
    )
    a = ap.parse_args(argv)

    if a.time_mesh:
        runs, row = [], None
        for _ in range(max(1, a.repeat)):
            pairs, diag = prepare(a.time_mesh, a.deform_only_weighted, not a.no_weld, a.subdivide)
            seconds, failed, _ = automatic_weights(pairs)
            runs.append(round(seconds, 4))
            row = {
                "file": os.path.basename(a.time_mesh),
                "vertices": sum(len(m.data.vertices) for _, ms in pairs for m in ms),
                "faces": sum(len(m.data.polygons) for _, ms in pairs for m in ms),
                "bones": diag["bones"],
                "heat_failed": failed,
                "unweighted_vertices": unweighted_vertices(pairs),
            }
        runs.sort()
        row.update(seconds_min=runs[0], seconds_median=runs[len(runs) // 2], runs=runs)
        print(json.dumps(row))
        return 0

    if not (a.dataset and a.out):
        ap.error("--dataset and --out are required (or --time-mesh FILE)")
    files = read_manifest(a.dataset, a.split)
    if a.files:
        wanted = [f.strip() for f in a.files.split(",") if f.strip()]
        unknown = sorted(set(wanted) - set(files))
        if unknown:
            ap.error(f"not in the manifest{' split ' + a.split if a.split else ''}: {', '.join(unknown)}")
        files = [f for f in files if f in wanted]
    os.makedirs(a.out, exist_ok=True)
    timings_path = os.path.join(a.out, "timings.json")
    timings = {}
    if os.path.exists(timings_path):
        with open(timings_path, encoding="utf-8") as f:
            timings = json.load(f)
    errors = 0
    for i, name in enumerate(files, 1):
        dst = os.path.join(a.out, name)
        try:
            row = rig_file(os.path.join(a.dataset, name), dst, a.deform_only_weighted, not a.no_weld)
        except Exception as e:  # one bad file must not stop the run
            errors += 1
            row = {"error": f"{type(e).__name__}: {e}"}
            if os.path.exists(dst):
                os.remove(dst)
        timings[name] = row
        print(f"[{i}/{len(files)}] {name}: {json.dumps(row)}", file=sys.stderr, flush=True)
        with open(timings_path, "w", encoding="utf-8") as f:
            json.dump(timings, f, indent=1, sort_keys=True)
    failed = sorted(k for k, v in timings.items() if v.get("heat_failed"))
    print(
        f"{len(files) - errors}/{len(files)} rigged; heat failed on {len(failed)}: {', '.join(failed) or '-'}",
        file=sys.stderr,
    )
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
