#!/usr/bin/env python3
"""Regenerates tests/corpus/ (hostile inputs for tests/malformed.rs) deterministically.

Every file is derived from one small valid rigged model (GLB, glTF with a data: URI,
and OBJ) by a single targeted corruption, so each one exercises one refusal path.
Run from anywhere:  python3 tests/corpus_gen.py
The output is byte-for-byte stable: no clocks, no system randomness, sorted JSON keys.
"""

import base64
import copy
import json
import os
import struct
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "corpus")
MAX_FILE = 64 * 1024

# --------------------------------------------------------------------------- base model


def base_model():
    """A box standing on the origin, skinned to a two-joint chain (Root -> Spine).

    Returns (gltf dict without buffers' uri, bin bytes). Lower corners are bound to
    Root, upper ones to Spine, so ground-truth extraction has real work to do.
    """
    pos = []
    for y in (0.0, 2.0):
        for x, z in ((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)):
            pos.append((x, y, z))
    nrm = [(x * 2, (y - 1.0), z * 2) for (x, y, z) in pos]
    # 12 triangles, outward winding does not matter for the loader.
    idx = [
        0, 2, 1, 0, 3, 2,  # bottom
        4, 5, 6, 4, 6, 7,  # top
        0, 1, 5, 0, 5, 4,
        1, 2, 6, 1, 6, 5,
        2, 3, 7, 2, 7, 6,
        3, 0, 4, 3, 4, 7,
    ]
    joints = [(0, 0, 0, 0)] * 4 + [(1, 0, 0, 0)] * 4
    weights = [(1.0, 0.0, 0.0, 0.0)] * 8
    ident = [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
    spine_ibm = list(ident)
    spine_ibm[13] = -1.0  # column-major translation (0, -1, 0)

    views = []
    blob = bytearray()

    def add(data, target=None):
        while len(blob) % 4:
            blob.append(0)
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)}
        if target:
            view["target"] = target
        views.append(view)
        blob.extend(data)
        return len(views) - 1

    v_pos = add(b"".join(struct.pack("<3f", *p) for p in pos), 34962)
    v_nrm = add(b"".join(struct.pack("<3f", *n) for n in nrm), 34962)
    v_idx = add(struct.pack("<%dH" % len(idx), *idx), 34963)
    v_jnt = add(b"".join(struct.pack("<4B", *j) for j in joints), 34962)
    v_wgt = add(b"".join(struct.pack("<4f", *w) for w in weights), 34962)
    v_ibm = add(struct.pack("<32f", *(ident + spine_ibm)))
    while len(blob) % 4:
        blob.append(0)

    doc = {
        "asset": {"version": "2.0", "generator": "rigserve corpus_gen.py"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {"name": "Armature", "children": [1, 3]},
            {"name": "Root", "children": [2]},
            {"name": "Spine", "translation": [0.0, 1.0, 0.0]},
            {"name": "Body", "mesh": 0, "skin": 0},
        ],
        "meshes": [
            {
                "name": "Box",
                "primitives": [
                    {
                        "attributes": {
                            "POSITION": 0,
                            "NORMAL": 1,
                            "JOINTS_0": 3,
                            "WEIGHTS_0": 4,
                        },
                        "indices": 2,
                        "mode": 4,
                    }
                ],
            }
        ],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": 5, "skeleton": 1}],
        "accessors": [
            {"bufferView": v_pos, "componentType": 5126, "count": 8, "type": "VEC3",
             "min": [-0.5, 0.0, -0.5], "max": [0.5, 2.0, 0.5]},
            {"bufferView": v_nrm, "componentType": 5126, "count": 8, "type": "VEC3"},
            {"bufferView": v_idx, "componentType": 5123, "count": len(idx), "type": "SCALAR"},
            {"bufferView": v_jnt, "componentType": 5121, "count": 8, "type": "VEC4"},
            {"bufferView": v_wgt, "componentType": 5126, "count": 8, "type": "VEC4"},
            {"bufferView": v_ibm, "componentType": 5126, "count": 2, "type": "MAT4"},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob)}],
    }
    return doc, bytes(blob)


BASE_DOC, BASE_BIN = base_model()

BASE_OBJ = b"""# unit box
o Box
v -0.5 0 -0.5
v 0.5 0 -0.5
v 0.5 0 0.5
v -0.5 0 0.5
v -0.5 2 -0.5
v 0.5 2 -0.5
v 0.5 2 0.5
v -0.5 2 0.5
vn 0 -1 0
vn 0 1 0
f 1//1 3//1 2//1
f 1//1 4//1 3//1
f 5//2 6//2 7//2
f 5//2 7//2 8//2
f 1 2 6
f 1 6 5
f 2 3 7
f 2 7 6
f 3 4 8
f 3 8 7
f 4 1 5
f 4 5 8
"""

# ------------------------------------------------------------------------------ helpers


def dumps(doc):
    return json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()


def chunk(kind, data, pad):
    while len(data) % 4:
        data += pad
    return struct.pack("<II", len(data), kind) + data


JSON_KIND = 0x4E4F534A
BIN_KIND = 0x004E4942


def glb(doc=None, bin_=None, json_bytes=None, version=2, chunks=None):
    """Packs a GLB; `chunks` overrides the chunk list entirely."""
    if chunks is None:
        jb = json_bytes if json_bytes is not None else dumps(doc)
        chunks = [chunk(JSON_KIND, jb, b" ")]
        if bin_ is not None:
            chunks.append(chunk(BIN_KIND, bin_, b"\0"))
    body = b"".join(chunks)
    return b"glTF" + struct.pack("<II", version, 12 + len(body)) + body


def gltf_text(doc, bin_=BASE_BIN):
    """A .gltf whose buffer 0 is the given bytes as a base64 data: URI."""
    d = copy.deepcopy(doc)
    if d.get("buffers") and "uri" not in d["buffers"][0]:
        d["buffers"][0]["uri"] = (
            "data:application/octet-stream;base64," + base64.b64encode(bin_).decode()
        )
    return dumps(d)


def variant(edit):
    """A deep copy of the base document with `edit(doc)` applied."""
    d = copy.deepcopy(BASE_DOC)
    edit(d)
    return d


def patch_bin(offset, data, bin_=BASE_BIN):
    b = bytearray(bin_)
    b[offset : offset + len(data)] = data
    return bytes(b)


def view_offset(i):
    return BASE_DOC["bufferViews"][i]["byteOffset"]


def acc(d, i):
    return d["accessors"][i]


def prim(d):
    return d["meshes"][0]["primitives"][0]


class XorShift:
    def __init__(self, seed):
        self.s = seed & 0xFFFFFFFFFFFFFFFF or 1

    def next(self):
        x = self.s
        x ^= (x << 13) & 0xFFFFFFFFFFFFFFFF
        x ^= x >> 7
        x ^= (x << 17) & 0xFFFFFFFFFFFFFFFF
        self.s = x
        return x

    def bytes(self, n):
        return bytes(self.next() & 0xFF for _ in range(n))


# ------------------------------------------------------------------------------- corpus

ENTRIES = []  # (file, stage, code, limits, description, bytes)


def add(name, data, code, desc, stage="load", limits="default"):
    assert isinstance(data, (bytes, bytearray)), name
    assert len(data) < MAX_FILE, (name, len(data))
    assert "\t" not in desc and "\n" not in desc
    ENTRIES.append((name, stage, code, limits, desc, bytes(data)))


BASE_GLB = glb(BASE_DOC, BASE_BIN)


def build():
    # --- GLB container -----------------------------------------------------------------
    add("glb_header_only.glb", BASE_GLB[:12], "glb_malformed",
        "GLB cut after the 12-byte header; header still claims the full length")
    add("glb_truncated_mid_json.glb", BASE_GLB[:300], "glb_malformed",
        "GLB cut in the middle of the JSON chunk")
    cut = BASE_GLB[: len(BASE_GLB) - 100]
    cut = cut[:8] + struct.pack("<I", len(cut)) + cut[12:]
    add("glb_truncated_mid_bin.glb", cut, "glb_malformed",
        "GLB cut inside the BIN chunk with the header length patched to match, so only the chunk length lies")
    add("glb_wrong_magic.glb", b"glTf" + BASE_GLB[4:], "unknown_format",
        "magic glTf instead of glTF: not recognised as any format")
    add("glb_version1.glb", BASE_GLB[:4] + struct.pack("<I", 1) + BASE_GLB[8:],
        "unsupported_version", "GLB container version 1")
    add("glb_header_length_past_end.glb",
        BASE_GLB[:8] + struct.pack("<I", len(BASE_GLB) + 4096) + BASE_GLB[12:],
        "glb_malformed", "header length 4 KiB longer than the file")
    jb = dumps(BASE_DOC)
    lying = bytearray(BASE_GLB)
    lying[12:16] = struct.pack("<I", len(BASE_GLB))
    add("glb_chunk_length_past_end.glb", bytes(lying), "glb_malformed",
        "JSON chunk length runs past the end of the file")
    over = bytearray(BASE_GLB)
    over[12:16] = struct.pack("<I", 0xFFFFFFFD)
    add("glb_chunk_length_u32_overflow.glb", bytes(over), "glb_malformed",
        "JSON chunk length 0xFFFFFFFD: offset + length + padding overflows u32 arithmetic")
    bin_off = 12 + 8 + ((len(jb) + 3) // 4 * 4)
    over_bin = bytearray(BASE_GLB)
    over_bin[bin_off : bin_off + 4] = struct.pack("<I", 0xFFFFFFFF)
    add("glb_bin_length_u32_max.glb", bytes(over_bin), "glb_malformed",
        "BIN chunk length 0xFFFFFFFF")
    add("glb_no_json_chunk.glb", glb(chunks=[chunk(BIN_KIND, BASE_BIN, b"\0")]),
        "glb_malformed", "GLB with only a BIN chunk")
    add("glb_two_json_chunks.glb",
        glb(chunks=[chunk(JSON_KIND, jb, b" "), chunk(JSON_KIND, jb, b" "),
                    chunk(BIN_KIND, BASE_BIN, b"\0")]),
        "glb_malformed", "two JSON chunks")
    add("glb_two_bin_chunks.glb",
        glb(chunks=[chunk(JSON_KIND, jb, b" "), chunk(BIN_KIND, BASE_BIN, b"\0"),
                    chunk(BIN_KIND, BASE_BIN, b"\0")]),
        "glb_malformed", "two BIN chunks")
    add("glb_json_not_utf8.glb",
        glb(json_bytes=jb.replace(b'"Armature"', b'"Arm\xff\xfeture"'), bin_=BASE_BIN),
        "gltf_json_invalid", "JSON chunk with invalid UTF-8 inside a string")
    add("glb_json_not_object.glb", glb(json_bytes=b"[1,2,3]", bin_=BASE_BIN),
        "gltf_json_invalid", "JSON chunk is an array, not an object")
    add("glb_json_trailing_garbage.glb", glb(json_bytes=jb + b"}}garbage", bin_=BASE_BIN),
        "gltf_json_invalid", "JSON chunk with trailing garbage after the object")
    add("gltf_json_deep_nesting.gltf", b'{"asset":{"version":"2.0"},"extras":' + b"[" * 30000 + b"]" * 30000 + b"}",
        "gltf_json_invalid", "30000 nested arrays: must hit the parser recursion limit, not the stack")
    add("gltf_json_deep_objects.gltf", b'{"a":' * 10000 + b"1" + b"}" * 10000,
        "gltf_json_invalid", "10000 nested objects")
    add("gltf_asset_version_1.gltf", gltf_text(variant(lambda d: d["asset"].update(version="1.0"))),
        "unsupported_version", "asset.version 1.0")
    add("gltf_asset_missing.gltf", gltf_text(variant(lambda d: d.pop("asset"))),
        "missing_asset", "no asset object (so no version)")
    add("glb_asset_missing.glb", glb(variant(lambda d: d.pop("asset")), BASE_BIN),
        "missing_asset", "GLB whose JSON has no asset object")
    add("gltf_asset_no_version.gltf", gltf_text(variant(lambda d: d["asset"].pop("version"))),
        "missing_asset", "asset without a version")
    add("gltf_asset_version_number.gltf", gltf_text(variant(lambda d: d["asset"].update(version=2.0))),
        "missing_asset", "asset.version is a number, not a string")
    add("gltf_asset_not_object.gltf", gltf_text(variant(lambda d: d.update(asset="2.0"))),
        "missing_asset", "asset is a string")
    add("gltf_wrong_field_type.gltf", gltf_text(variant(lambda d: d.update(nodes={"0": {}}))),
        "gltf_invalid", "nodes is an object instead of an array")

    # --- out-of-range indices -------------------------------------------------------------
    add("oob_accessor.glb", glb(variant(lambda d: prim(d)["attributes"].update(POSITION=99)), BASE_BIN),
        "index_out_of_range", "POSITION refers to accessor 99")
    add("oob_buffer_view.glb", glb(variant(lambda d: acc(d, 0).update(bufferView=42)), BASE_BIN),
        "index_out_of_range", "POSITION accessor refers to bufferView 42")
    add("oob_buffer.glb", glb(variant(lambda d: d["bufferViews"][0].update(buffer=7)), BASE_BIN),
        "index_out_of_range", "bufferView refers to buffer 7")
    add("oob_node_child.glb", glb(variant(lambda d: d["nodes"][1]["children"].append(99)), BASE_BIN),
        "index_out_of_range", "node child 99 of 4 nodes")
    add("oob_scene_node.glb", glb(variant(lambda d: d["scenes"][0].update(nodes=[0, 50])), BASE_BIN),
        "index_out_of_range", "scene lists node 50")
    add("oob_scene.glb", glb(variant(lambda d: d.update(scene=5)), BASE_BIN),
        "index_out_of_range", "default scene 5 of 1")
    add("oob_mesh.glb", glb(variant(lambda d: d["nodes"][3].update(mesh=9)), BASE_BIN),
        "index_out_of_range", "node instances mesh 9")
    add("oob_skin.glb", glb(variant(lambda d: d["nodes"][3].update(skin=9)), BASE_BIN),
        "index_out_of_range", "node uses skin 9")
    add("oob_skin_joint_node.glb", glb(variant(lambda d: d["skins"][0].update(joints=[1, 99])), BASE_BIN),
        "index_out_of_range", "skin joint list names node 99")
    bad_joint = patch_bin(view_offset(3) + 4 * 5, bytes([7, 0, 0, 0]))
    add("oob_joint_in_joints0.glb", glb(BASE_DOC, bad_joint),
        "index_out_of_range", "JOINTS_0 of vertex 5 names joint 7 of a 2-joint skin (weight 1)",
        stage="extract")
    bad_index = patch_bin(view_offset(2) + 2 * 7, struct.pack("<H", 200))
    add("oob_vertex_index.glb", glb(BASE_DOC, bad_index),
        "index_out_of_range", "index buffer refers to vertex 200 of 8")

    # --- accessors ------------------------------------------------------------------------
    add("acc_past_view_end.glb", glb(variant(lambda d: acc(d, 0).update(byteOffset=64)), BASE_BIN),
        "accessor_out_of_bounds", "POSITION accessor starts 64 bytes into a 96-byte view")
    add("acc_count_past_view_end.glb", glb(variant(lambda d: acc(d, 0).update(count=9)), BASE_BIN),
        "accessor_out_of_bounds", "POSITION count 9 over an 8-vertex view")
    add("acc_view_past_buffer.glb",
        glb(variant(lambda d: d["bufferViews"][0].update(byteOffset=len(BASE_BIN) - 8)), BASE_BIN),
        "gltf_invalid", "bufferView runs past the end of its buffer")
    add("acc_view_offset_u64_max.glb",
        glb(variant(lambda d: d["bufferViews"][0].update(byteOffset=2**64 - 1)), BASE_BIN),
        "gltf_invalid", "bufferView byteOffset u64::MAX: offset + length overflows")
    add("acc_stride_too_small.glb", glb(variant(lambda d: d["bufferViews"][0].update(byteStride=4)), BASE_BIN),
        "gltf_invalid", "byteStride 4 for a 12-byte VEC3 element")
    add("acc_stride_huge.glb", glb(variant(lambda d: d["bufferViews"][0].update(byteStride=2**63)), BASE_BIN),
        "bad_byte_stride", "byteStride 2^63: stride x count would overflow 64-bit math")
    # --- what glTF 2.0 forbids and a lenient reader would read anyway -----------------
    for stride in (13, 256, 2, 0, 254, 1 << 20):
        add(f"spec_stride_{stride}.glb",
            glb(variant(lambda d, s=stride: d["bufferViews"][0].update(byteStride=s)), BASE_BIN),
            "bad_byte_stride", f"byteStride {stride}: glTF allows multiples of 4 from 4 to 252")
    add("spec_acc_offset_unaligned.glb",
        glb(variant(lambda d: acc(d, 0).update(byteOffset=2, count=7)), BASE_BIN),
        "misaligned_accessor", "float POSITION accessor at byteOffset 2")
    add("spec_view_offset_unaligned.glb",
        glb(variant(lambda d: d["bufferViews"][0].update(byteOffset=2)), BASE_BIN),
        "misaligned_accessor", "the POSITION bufferView starts at byte 2: ordinary data, floats off by 2 bytes")
    add("spec_indices_offset_odd.glb",
        glb(variant(lambda d: acc(d, 2).update(byteOffset=1, count=35)), BASE_BIN),
        "misaligned_accessor", "u16 indices at byteOffset 1")
    add("spec_normal_offset_unaligned.glb",
        glb(variant(lambda d: acc(d, 1).update(byteOffset=1, count=7)), BASE_BIN),
        "misaligned_accessor", "float NORMAL accessor at byteOffset 1")
    add("spec_weights_offset_unaligned.glb",
        glb(variant(lambda d: acc(d, 4).update(byteOffset=2, count=7)), BASE_BIN),
        "misaligned_accessor", "float WEIGHTS_0 accessor at byteOffset 2")
    add("spec_ibm_offset_unaligned.glb",
        glb(variant(lambda d: acc(d, 5).update(byteOffset=6, count=1)), BASE_BIN),
        "misaligned_accessor", "float inverse bind matrices at byteOffset 6")
    for ct, name in ((5121, "ubyte"), (5120, "byte"), (5123, "ushort"), (5122, "short")):
        add(f"spec_position_{name}_unquantized.glb",
            glb(variant(lambda d, ct=ct: acc(d, 0).update(componentType=ct)), BASE_BIN),
            "unsupported_component_type", f"POSITION as {name} without KHR_mesh_quantization in extensionsUsed")
    add("spec_normal_byte_unquantized.glb",
        glb(variant(lambda d: acc(d, 1).update(componentType=5120, normalized=True)), BASE_BIN),
        "unsupported_component_type", "NORMAL as normalized byte without KHR_mesh_quantization")
    add("spec_indices_signed_short.glb",
        glb(variant(lambda d: acc(d, 2).update(componentType=5122)), BASE_BIN),
        "unsupported_component_type", "indices as signed short")
    add("spec_indices_signed_byte.glb",
        glb(variant(lambda d: acc(d, 2).update(componentType=5120)), BASE_BIN),
        "unsupported_component_type", "indices as signed byte")
    for ext in ("EXT_made_up", "KHR_mesh_gpu_instancing", "KHR_animation_pointer", "ADOBE_materials_thin_transparency", ""):
        add(f"spec_required_{ext or 'empty_name'}.glb",
            glb(variant(lambda d, e=ext: d.update(extensionsUsed=[e], extensionsRequired=[e])), BASE_BIN),
            "unsupported_required_extension", f"extensionsRequired names {ext!r}, which rigserve does not read")
    add("acc_count_u32_max.glb", glb(variant(lambda d: acc(d, 0).update(count=2**32 - 1)), BASE_BIN),
        "too_many_vertices", "POSITION count u32::MAX: refused before allocation")
    add("acc_count_2pow53.glb", glb(variant(lambda d: acc(d, 0).update(count=2**53)), BASE_BIN),
        "too_many_vertices", "POSITION count 2^53: refused before allocation")
    add("acc_count_no_view_huge.glb",
        glb(variant(lambda d: acc(d, 0).update(count=2**40) or acc(d, 0).pop("bufferView")), BASE_BIN),
        "too_many_vertices", "POSITION without bufferView (implicit zeros) and count 2^40: refused before allocation")
    add("acc_indices_count_u32_max.glb", glb(variant(lambda d: acc(d, 2).update(count=2**32 - 1)), BASE_BIN),
        "too_many_triangles", "index accessor count u32::MAX: refused before allocation")
    add("acc_ibm_count_2pow53.glb", glb(variant(lambda d: acc(d, 5).update(count=2**53)), BASE_BIN),
        "too_many_vertices", "inverseBindMatrices count 2^53: refused before allocation")
    add("acc_count_negative.glb", glb(variant(lambda d: acc(d, 0).update(count=-1)), BASE_BIN),
        "gltf_invalid", "POSITION count -1")
    add("acc_count_1e300.glb", glb(json_bytes=dumps(BASE_DOC).replace(b'"count":8', b'"count":1e300', 1),
                                   bin_=BASE_BIN),
        "gltf_invalid", "POSITION count 1e300 (not an integer)")
    add("acc_bad_component_type.glb", glb(variant(lambda d: acc(d, 0).update(componentType=5130)), BASE_BIN),
        "gltf_invalid", "POSITION componentType 5130 (double) is not glTF")
    add("acc_bad_type.glb", glb(variant(lambda d: acc(d, 0).update(type="VEC7")), BASE_BIN),
        "gltf_invalid", "POSITION type VEC7")
    add("acc_position_vec2.glb", glb(variant(lambda d: acc(d, 0).update(type="VEC2")), BASE_BIN),
        "gltf_invalid", "POSITION of type VEC2")
    add("acc_indices_float.glb", glb(variant(lambda d: acc(d, 2).update(componentType=5126, count=18)), BASE_BIN),
        "unsupported_component_type", "indices stored as float")
    add("acc_indices_normalized.glb", glb(variant(lambda d: acc(d, 2).update(normalized=True)), BASE_BIN),
        "gltf_invalid", "indices accessor with normalized: true (forbidden; would read as 0 or 1)")

    def sparse(d, count, indices):
        # Sparse data appended after the base buffer: index list then VEC3 values.
        extra = struct.pack("<%dI" % len(indices), *indices)
        extra += struct.pack("<%df" % (3 * len(indices)), *([1.0, 1.0, 1.0] * len(indices)))
        off = len(BASE_BIN)
        d["bufferViews"].append({"buffer": 0, "byteOffset": off, "byteLength": 4 * len(indices)})
        d["bufferViews"].append({"buffer": 0, "byteOffset": off + 4 * len(indices),
                                 "byteLength": 12 * len(indices)})
        n = len(d["bufferViews"])
        acc(d, 0)["sparse"] = {
            "count": count,
            "indices": {"bufferView": n - 2, "componentType": 5125},
            "values": {"bufferView": n - 1},
        }
        d["buffers"][0]["byteLength"] = off + 16 * len(indices)
        return BASE_BIN + extra

    d = copy.deepcopy(BASE_DOC)
    b = sparse(d, 2, [1, 2])
    acc(d, 0)["sparse"]["values"]["byteOffset"] = 2
    add("spec_sparse_values_unaligned.glb", glb(d, b), "misaligned_accessor",
        "sparse POSITION values at byteOffset 2")
    d = copy.deepcopy(BASE_DOC)
    b = sparse(d, 2, [1, 2])
    acc(d, 0)["sparse"]["indices"]["byteOffset"] = 1
    add("spec_sparse_indices_unaligned.glb", glb(d, b), "misaligned_accessor",
        "sparse u32 indices at byteOffset 1")
    d = copy.deepcopy(BASE_DOC)
    b = sparse(d, 2, [1, 1000])
    add("acc_sparse_index_oob.glb", glb(d, b), "index_out_of_range",
        "sparse POSITION substitution targets element 1000 of 8")
    d = copy.deepcopy(BASE_DOC)
    b = sparse(d, 9, [0, 1, 2, 3, 4, 5, 6, 7, 7])
    add("acc_sparse_count_gt_count.glb", glb(d, b), "gltf_invalid",
        "sparse count 9 over an 8-element accessor")
    d = copy.deepcopy(BASE_DOC)
    b = sparse(d, 2, [1, 2])
    acc(d, 0)["sparse"]["count"] = 2**53
    acc(d, 0)["count"] = 2**53
    acc(d, 0).pop("bufferView")
    add("acc_sparse_count_2pow53.glb", glb(d, b), "too_many_vertices",
        "sparse accessor with count and sparse.count 2^53: refused before allocation")
    d = copy.deepcopy(BASE_DOC)
    b = sparse(d, 2, [1, 2])
    acc(d, 0)["sparse"]["indices"]["componentType"] = 5126
    add("acc_sparse_float_indices.glb", glb(d, b), "gltf_invalid",
        "sparse indices stored as float")
    d = copy.deepcopy(BASE_DOC)
    b = sparse(d, 2, [1, 2])
    acc(d, 0)["sparse"]["values"]["byteOffset"] = 2**64 - 8
    add("acc_sparse_values_offset_huge.glb", glb(d, b), "accessor_out_of_bounds",
        "sparse values byteOffset near u64::MAX")

    # --- URIs -----------------------------------------------------------------------------
    def with_uri(uri):
        return variant(lambda d: d["buffers"][0].update(uri=uri))

    add("uri_buffer_http.gltf", gltf_text(with_uri("http://169.254.169.254/latest/meta-data/")),
        "external_uri", "buffer uri http:// (never fetched)")
    add("uri_buffer_relative.gltf", gltf_text(with_uri("../../etc/shadow")),
        "external_uri", "buffer uri relative file path")
    add("uri_buffer_file_passwd.gltf", gltf_text(with_uri("file:///etc/passwd")),
        "external_uri", "buffer uri file:///etc/passwd")
    add("uri_buffer_in_glb.glb", glb(with_uri("model.bin"), BASE_BIN),
        "external_uri", "GLB whose buffer 0 points at an external file instead of the BIN chunk")
    add("uri_image_http.glb",
        glb(variant(lambda d: d.update(images=[{"uri": "http://example.com/t.png"}])), BASE_BIN),
        "external_uri", "image uri http://")
    bomb = "data:application/octet-stream;base64," + "A" * (24 * 1024)
    add("uri_data_bomb.gltf", gltf_text(with_uri(bomb)), "file_too_large",
        "data: URI decoding to 18 KiB under a 16 KiB byte cap (base64 never expands, so the whole-file cap answers first)",
        limits="small")
    add("uri_data_not_base64.gltf",
        gltf_text(with_uri("data:application/octet-stream," + "%00" * 600)),
        "gltf_invalid", "data: URI with percent-encoding instead of base64")
    add("uri_data_bad_base64.gltf",
        gltf_text(with_uri("data:application/octet-stream;base64,@@@@" + "A" * 700)),
        "gltf_invalid", "data: URI with characters outside the base64 alphabet")
    add("uri_data_no_comma.gltf",
        gltf_text(with_uri("data:application/octet-stream;base64")),
        "gltf_invalid", "data: URI without a comma")
    add("uri_buffer_short.gltf",
        gltf_text(variant(lambda d: d["buffers"][0].update(byteLength=1 << 20))),
        "gltf_invalid", "buffer claims 1 MiB but its data: URI holds 552 bytes")

    # --- extensions -----------------------------------------------------------------------
    def draco(d):
        d["extensionsUsed"] = ["KHR_draco_mesh_compression"]
        d["extensionsRequired"] = ["KHR_draco_mesh_compression"]
        prim(d)["extensions"] = {
            "KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}
        }

    add("ext_draco_required.glb", glb(variant(draco), BASE_BIN),
        "compressed_data_invalid",
        "KHR_draco_mesh_compression in extensionsRequired, its bufferView plain floats, not a Draco stream")

    def meshopt(d):
        d["extensionsUsed"] = ["EXT_meshopt_compression"]
        d["bufferViews"][0]["extensions"] = {
            "EXT_meshopt_compression": {"buffer": 0, "byteLength": 96, "byteStride": 12,
                                        "count": 8, "mode": "ATTRIBUTES"}
        }

    add("ext_meshopt.glb", glb(variant(meshopt), BASE_BIN),
        "compressed_data_invalid",
        "EXT_meshopt_compression bufferView whose compressed bytes are plain floats")
    add("ext_draco_primitive_only.glb",
        glb(variant(lambda d: prim(d).update(extensions={"KHR_draco_mesh_compression": {}})), BASE_BIN),
        "compressed_data_invalid",
        "Draco extension on a primitive without being declared, with no bufferView")

    # --- geometry -------------------------------------------------------------------------
    nan = struct.pack("<f", float("nan"))
    add("geo_nan_position.glb", glb(BASE_DOC, patch_bin(view_offset(0) + 12 * 3 + 4, nan)),
        "non_finite", "vertex 3 has y = NaN")
    inf = struct.pack("<f", float("inf"))
    add("geo_inf_position.glb", glb(BASE_DOC, patch_bin(view_offset(0) + 12 * 6, inf)),
        "non_finite", "vertex 6 has x = +Inf")

    def inf_matrix(d):
        m = [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
        d["nodes"][0]["matrix"] = m

    js = dumps(variant(inf_matrix)).replace(b"[1.0,0,0,0,0,1.0,0,0,0,0,1.0,0,0,0,0,1.0]",
                                            b"[1.0,0,0,0,0,1.0,0,0,0,0,1.0,0,1e39,0,0,1.0]")
    assert b"1e39" in js
    add("geo_inf_node_matrix.glb", glb(json_bytes=js, bin_=BASE_BIN),
        "non_finite", "root node matrix translation 1e39 (overflows f32 to Inf)")
    def overflow(d):
        d["nodes"][0]["scale"] = [1e30] * 3
        d["nodes"][3]["scale"] = [1e30] * 3
        del d["nodes"][3]["skin"]

    add("geo_overflowing_world_matrix.glb", glb(variant(overflow), BASE_BIN),
        "non_finite", "two finite node scales of 1e30 whose product overflows f32")
    flat = b"".join(struct.pack("<3f", 0.25, 1.0, 0.25) for _ in range(8))
    add("geo_zero_area.glb", glb(BASE_DOC, patch_bin(view_offset(0), flat)),
        "degenerate_mesh", "all 8 vertices at one point: every triangle has zero area")
    line = b"".join(struct.pack("<3f", float(i), 0.0, 0.0) for i in range(8))
    add("geo_collinear.glb", glb(BASE_DOC, patch_bin(view_offset(0), line)),
        "degenerate_mesh", "all vertices on the x axis")
    add("geo_empty_scene.glb", glb(variant(lambda d: d["scenes"][0].update(nodes=[])), BASE_BIN),
        "empty_scene", "the default scene has no nodes")
    add("geo_no_meshes.gltf", dumps({"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}],
                                     "nodes": [{"name": "lonely"}]}),
        "empty_scene", "a node tree without any mesh")
    def empty_prim(d):
        acc(d, 0)["count"] = 0
        del prim(d)["indices"]

    add("geo_empty_primitive.glb", glb(variant(empty_prim), BASE_BIN),
        "empty_scene", "POSITION count 0")

    def points_lines(d):
        p = prim(d)
        p["mode"] = 0
        p2 = copy.deepcopy(p)
        p2["mode"] = 1
        p3 = copy.deepcopy(p)
        p3["mode"] = 3
        d["meshes"][0]["primitives"] = [p, p2, p3]

    add("geo_points_lines_only.glb", glb(variant(points_lines), BASE_BIN),
        "no_triangles", "primitives of modes POINTS, LINES and LINE_STRIP only")
    add("geo_mode_9.gltf", gltf_text(variant(lambda d: prim(d).update(mode=9))),
        "gltf_invalid", "primitive mode 9 does not exist")
    add("geo_no_position.glb", glb(variant(lambda d: prim(d)["attributes"].pop("POSITION")), BASE_BIN),
        "gltf_invalid", "a primitive without POSITION")

    # --- node hierarchy -------------------------------------------------------------------
    def cycle(d):
        d["nodes"][0]["children"] = [3]
        d["nodes"][1]["children"] = [2]
        d["nodes"][2]["children"] = [1]

    add("hier_cycle.glb", glb(variant(cycle), BASE_BIN), "bad_hierarchy",
        "nodes 1 and 2 are each other's child (outside the scene)")

    def cycle_from_root(d):
        d["nodes"][2]["children"] = [0]

    add("hier_cycle_through_root.glb", glb(variant(cycle_from_root), BASE_BIN), "bad_hierarchy",
        "the scene root is its own grandchild")
    add("hier_two_parents.glb", glb(variant(lambda d: d["nodes"][0]["children"].append(2)), BASE_BIN),
        "bad_hierarchy", "node 2 is a child of both node 0 and node 1")
    add("hier_self_child.glb", glb(variant(lambda d: d["nodes"][2].update(children=[2])), BASE_BIN),
        "bad_hierarchy", "node 2 lists itself as a child")
    add("hier_root_listed_twice.glb", glb(variant(lambda d: d["scenes"][0].update(nodes=[0, 0])), BASE_BIN),
        "bad_hierarchy", "the scene lists node 0 twice")
    add("hier_root_has_parent.glb", glb(variant(lambda d: d["scenes"][0].update(nodes=[0, 3])), BASE_BIN),
        "bad_hierarchy", "the scene lists node 3, a child of node 0, as a root")
    n = 3000
    chain = {"asset": {"version": "2.0"}, "scenes": [{"nodes": []}],
             "nodes": [{"children": [(i + 1) % n]} for i in range(n)]}
    add("hier_long_cycle.gltf", dumps(chain), "bad_hierarchy",
        "a 3000-node ring outside the scene (cycle detection must stay linear)")

    # --- caps -----------------------------------------------------------------------------
    def many_instances(d):
        for i in range(9):
            d["nodes"].append({"mesh": 0})
            d["nodes"][0]["children"].append(len(d["nodes"]) - 1)

    def many_sparse_instances(d):
        # Two triangles over all 8 vertices, so the vertex cap is crossed first.
        d["accessors"].append(dict(acc(d, 2), count=6))
        d["meshes"].append({"primitives": [{"attributes": {"POSITION": 0}, "indices": 6}]})
        for i in range(9):
            d["nodes"].append({"mesh": 1})
            d["nodes"][0]["children"].append(len(d["nodes"]) - 1)

    add("cap_too_many_vertices.glb", glb(variant(many_sparse_instances), BASE_BIN),
        "too_many_vertices", "80 vertices in 10 instances of one mesh, over a cap of 64",
        limits="small")

    def strip_instances(d):
        prim(d)["mode"] = 5
        many_instances(d)

    add("cap_too_many_triangles.glb", glb(variant(strip_instances), BASE_BIN),
        "too_many_triangles", "triangle strips: 34 triangles each, 340 over a cap of 64",
        limits="small")
    add("cap_too_many_nodes.gltf",
        dumps({"asset": {"version": "2.0"}, "nodes": [{} for _ in range(65)]}),
        "gltf_invalid", "65 nodes over a cap of 64", limits="small")
    add("cap_file_too_large.glb", BASE_GLB + b"\0" * (17 * 1024 - len(BASE_GLB)),
        "file_too_large", "17 KiB file over a 16 KiB cap", limits="small")

    # A few dozen kilobytes of JSON that multiply into millions of primitive instances.
    n_nodes, n_prims = 2000, 1300
    amp = {
        "asset": {"version": "2.0"},
        "accessors": [{"componentType": 5126, "count": 0, "type": "VEC3"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}] * n_prims}],
        "nodes": [{"mesh": 0} for _ in range(n_nodes)],
    }
    add("amp_empty_primitive_instances.gltf", dumps(amp), "gltf_invalid",
        "2000 nodes x 1300 empty primitives: 2.6M instances from 60 KiB (each must not cost a Part)")
    amp["meshes"][0]["primitives"] = [{"mode": 0}] * 2500
    amp["nodes"] = [{"mesh": 0} for _ in range(3000)]
    add("amp_point_primitive_instances.gltf", dumps(amp), "gltf_invalid",
        "3000 nodes x 2500 POINTS primitives: 7.5M skipped instances from 60 KiB")
    strip = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)).decode()}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
            {"componentType": 5125, "count": 5_000_000, "type": "SCALAR"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 5}]}],
        "nodes": [{"mesh": 0}],
    }
    n_skins = 1000
    shared_ibm = {
        "asset": {"version": "2.0"},
        "buffers": strip["buffers"],
        "bufferViews": strip["bufferViews"],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
            {"componentType": 5121, "count": 3, "type": "VEC4"},
            {"componentType": 5126, "count": 3, "type": "VEC4"},
            {"componentType": 5126, "count": 4096, "type": "MAT4"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 1, "WEIGHTS_0": 2}}]}],
        "nodes": [{"mesh": 0, "skin": i} for i in range(n_skins)],
        "skins": [{"joints": [0], "inverseBindMatrices": 3}] * n_skins,
    }
    add("amp_shared_ibm_skins.gltf", dumps(shared_ibm), "gltf_invalid",
        "1000 one-joint skins sharing a 4096-matrix accessor: 4M bind matrices to read, over the 2M cap")
    add("amp_zero_index_strip.gltf", dumps(strip), "too_many_triangles",
        "a 5M-index implicit-zero triangle strip (5M triangles, cap 2M): refused before allocation")

    # --- OBJ ------------------------------------------------------------------------------
    add("obj_bad_face_index.obj", BASE_OBJ + b"f 1 2 99\n", "obj_invalid",
        "face refers to vertex 99 of 8")
    add("obj_zero_face_index.obj", BASE_OBJ + b"f 0 1 2\n", "obj_invalid",
        "face index 0 (OBJ is 1-based)")
    add("obj_negative_face_index.obj", BASE_OBJ + b"f -1 -2 -9\n", "obj_invalid",
        "relative face index -9 with 8 vertices")
    add("obj_huge_face_index.obj", BASE_OBJ + b"f 1 2 99999999999999999999999\n", "obj_invalid",
        "face index beyond i64")
    add("obj_bad_normal_index.obj", BASE_OBJ + b"f 1//7 2//1 3//1\n", "obj_invalid",
        "face normal index 7 of 2")
    add("obj_nan.obj", BASE_OBJ.replace(b"v 0.5 2 0.5", b"v 0.5 nan 0.5"), "non_finite",
        "a vertex coordinate is nan")
    add("obj_inf.obj", BASE_OBJ.replace(b"v 0.5 2 0.5", b"v 0.5 1e39 0.5"), "non_finite",
        "a vertex coordinate overflows f32 (1e39)")
    add("obj_no_faces.obj", b"".join(l + b"\n" for l in BASE_OBJ.splitlines() if not l.startswith(b"f ")),
        "empty_scene", "vertices but no faces")
    add("obj_one_corner_face.obj", BASE_OBJ + b"f 1\n", "obj_invalid", "a face with one corner")
    add("obj_bad_number.obj", BASE_OBJ.replace(b"v 0.5 2 0.5", b"v 0.5 two 0.5"), "obj_invalid",
        "a vertex coordinate that is not a number")
    add("obj_degenerate.obj", b"v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\n", "degenerate_mesh",
        "one triangle with collinear corners")
    add("obj_sliver_1e38.obj", BASE_OBJ.replace(b"v 0.5 2 0.5", b"v 0.5 2 1e38"), "degenerate_mesh",
        "one corner 1e38 out: areas overflow f32 in the file's frame and vanish in the unit frame")
    add("obj_too_many_vertices.obj",
        b"".join(b"v %d 0 %d\n" % (i % 10, i // 10) for i in range(100)) + b"f 1 2 11\n",
        "too_many_vertices", "100 vertices over a cap of 64", limits="small")
    add("obj_face_5000_corners.obj",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf" + b" 1 2 3" * 1700 + b"\n",
        "obj_invalid", "a face with 5100 corners (over 4096)")

    # --- not a mesh at all ----------------------------------------------------------------
    rng = XorShift(0x5EED)
    add("random_bytes.bin", rng.bytes(4096), "unknown_format", "4 KiB of xorshift noise")
    add("empty.bin", b"", "empty_file", "zero bytes")
    add("whitespace.txt", b" \n\t\r\n   \n", "unknown_format", "only whitespace")
    add("png_header.png",
        b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\0\x01\0\0\0\x01\x08\x06\0\0\0\x1f\x15\xc4\x89",
        "unknown_format", "PNG signature and IHDR")
    add("zip_header.zip", b"PK\x03\x04\x14\0\0\0\x08\0" + b"\0" * 20 + b"model.glb", "unknown_format",
        "ZIP local file header")
    add("nul_bytes.bin", b"\0" * 64, "unknown_format", "64 NUL bytes")
    add("json_text_not_gltf.gltf", b'{"hello": "world"}', "missing_asset",
        "a JSON object that is not glTF")

    # --- ground-truth extraction ----------------------------------------------------------
    singular = patch_bin(view_offset(5) + 64, struct.pack("<16f", *([0.0] * 16)))
    add("gt_singular_ibm.glb", glb(BASE_DOC, singular), "gltf_invalid",
        "the Spine joint's inverse bind matrix is all zeros", stage="extract")
    add("gt_joints_weights_count_mismatch.glb",
        glb(variant(lambda d: acc(d, 4).update(count=7)), BASE_BIN), "gltf_invalid",
        "WEIGHTS_0 has 7 elements for 8 vertices", stage="extract")
    add("gt_joints_float.glb",
        glb(variant(lambda d: acc(d, 3).update(componentType=5126)), BASE_BIN),
        "gltf_invalid", "JOINTS_0 stored as float", stage="extract")
    add("gt_joints_scalar.glb",
        glb(variant(lambda d: acc(d, 3).update(type="SCALAR")), BASE_BIN),
        "gltf_invalid", "JOINTS_0 of type SCALAR", stage="extract")
    add("gt_joints_normalized.glb",
        glb(variant(lambda d: acc(d, 3).update(normalized=True)), BASE_BIN),
        "gltf_invalid", "JOINTS_0 with normalized: true", stage="extract")
    add("skin_ibm_too_few.glb",
        glb(variant(lambda d: acc(d, 5).update(count=1)), BASE_BIN),
        "gltf_invalid", "one inverse bind matrix for two joints (refused while placing the skin)")


def main():
    build()
    names = [e[0] for e in ENTRIES]
    assert len(names) == len(set(names)), "duplicate file name"
    os.makedirs(OUT, exist_ok=True)
    keep = set(names) | {"EXPECTED.tsv", "README.md", "base.glb", "base.gltf", "base.obj"}
    for f in os.listdir(OUT):
        if f not in keep:
            os.remove(os.path.join(OUT, f))
    # The valid bases live beside the corpus (not in EXPECTED.tsv): they must load.
    bases = {"base.glb": BASE_GLB, "base.gltf": gltf_text(BASE_DOC), "base.obj": BASE_OBJ}
    for name, data in list(bases.items()) + [(e[0], e[5]) for e in ENTRIES]:
        with open(os.path.join(OUT, name), "wb") as f:
            f.write(data)
    with open(os.path.join(OUT, "EXPECTED.tsv"), "w", newline="\n") as f:
        f.write("file\tstage\texpected_code\tlimits\tdescription\n")
        for name, stage, code, limits, desc, _ in ENTRIES:
            f.write(f"{name}\t{stage}\t{code}\t{limits}\t{desc}\n")
    print(f"wrote {len(ENTRIES)} corpus files + {len(bases)} bases to {OUT}", file=sys.stderr)


if __name__ == "__main__":
    main()
