"""Checks for the synthetic rig generator.

    python3 -m pytest training/synth -q
    python3 -m training.synth.test_generate      # without pytest
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile

import numpy as np

from .generate import CATEGORIES, character_rng, file_name, main, make_character, pick_category, BUILDERS
from .glb import CHUNK_BIN, CHUNK_JSON, GLB_MAGIC, TYPE_COMPONENTS, read_accessor, read_glb, world_matrices

SEED = 1234
PER_CATEGORY = 3

MIXAMO_PARENTS = {
    "Spine": "Hips", "Spine1": "Spine", "Spine2": "Spine1", "Neck": "Spine2", "Head": "Neck",
    "LeftShoulder": "Spine2", "LeftArm": "LeftShoulder", "LeftForeArm": "LeftArm", "LeftHand": "LeftForeArm",
    "RightShoulder": "Spine2", "RightArm": "RightShoulder", "RightForeArm": "RightArm", "RightHand": "RightForeArm",
    "LeftUpLeg": "Hips", "LeftLeg": "LeftUpLeg", "LeftFoot": "LeftLeg", "LeftToeBase": "LeftFoot",
    "RightUpLeg": "Hips", "RightLeg": "RightUpLeg", "RightFoot": "RightLeg", "RightToeBase": "RightFoot",
}

_cache: dict = {}


def samples():
    """(category, index, bytes) for a few characters of every category, generated once."""
    if "s" not in _cache:
        out = []
        for ci, cat in enumerate(CATEGORIES):
            for k in range(PER_CATEGORY):
                idx = ci * 100 + k
                data, got, _ = make_character(SEED, idx, cat)
                assert got == cat
                out.append((cat, idx, data))
        _cache["s"] = out
    return _cache["s"]


def joint_parents(doc: dict) -> dict:
    """Joint node -> nearest ancestor that is also a joint (or None)."""
    nodes = doc["nodes"]
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}
    joints = set(doc["skins"][0]["joints"])
    out = {}
    for j in joints:
        p = parent.get(j)
        while p is not None and p not in joints:
            p = parent.get(p)
        out[j] = p
    return out


def test_glb_container_and_layout():
    for cat, idx, data in samples():
        magic, version, total = struct.unpack_from("<III", data, 0)
        assert magic == GLB_MAGIC and version == 2 and total == len(data), (cat, idx)
        assert total % 4 == 0
        jlen, jtype = struct.unpack_from("<II", data, 12)
        assert jtype == CHUNK_JSON and jlen % 4 == 0
        blen, btype = struct.unpack_from("<II", data, 20 + jlen)
        assert btype == CHUNK_BIN and blen % 4 == 0
        assert 28 + jlen + blen == total
        doc, binary = read_glb(data)
        assert doc["asset"]["version"] == "2.0"
        assert doc["buffers"][0]["byteLength"] <= blen < doc["buffers"][0]["byteLength"] + 4
        for v in doc["bufferViews"]:
            assert v["byteOffset"] % 4 == 0
            assert v["byteOffset"] + v["byteLength"] <= len(binary)
        for k, a in enumerate(doc["accessors"]):
            v = doc["bufferViews"][a["bufferView"]]
            size = read_accessor(doc, binary, k).dtype.itemsize
            assert a["count"] * TYPE_COMPONENTS[a["type"]] * size <= v["byteLength"]
            assert (v["byteOffset"] + a.get("byteOffset", 0)) % size == 0


def test_meshes_attributes_and_bounds():
    for cat, idx, data in samples():
        doc, binary = read_glb(data)
        skinned_nodes = [n for n in doc["nodes"] if "skin" in n]
        assert skinned_nodes, cat
        total = 0
        for n in doc["nodes"]:
            if "mesh" not in n:
                continue
            for p in doc["meshes"][n["mesh"]]["primitives"]:
                attrs = p["attributes"]
                pos = read_accessor(doc, binary, attrs["POSITION"])
                acc = doc["accessors"][attrs["POSITION"]]
                assert np.array_equal(pos.min(0), np.array(acc["min"], dtype=np.float32))
                assert np.array_equal(pos.max(0), np.array(acc["max"], dtype=np.float32))
                nrm = read_accessor(doc, binary, attrs["NORMAL"])
                assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
                idx_ = read_accessor(doc, binary, p["indices"])
                assert len(idx_) % 3 == 0 and idx_.max() < len(pos)
                assert ("JOINTS_0" in attrs) == ("skin" in n)
                if "skin" in n:
                    total += len(pos)
        assert total > 0


def test_weights_are_normalized_and_valid():
    for cat, idx, data in samples():
        doc, binary = read_glb(data)
        n_joints = len(doc["skins"][0]["joints"])
        for n in doc["nodes"]:
            if "skin" not in n:
                continue
            for p in doc["meshes"][n["mesh"]]["primitives"]:
                j = read_accessor(doc, binary, p["attributes"]["JOINTS_0"]).astype(np.int64)
                w = read_accessor(doc, binary, p["attributes"]["WEIGHTS_0"])
                assert w.dtype == np.float32 and w.shape[1] == 4
                assert np.all(w >= 0)
                assert np.allclose(w.sum(1, dtype=np.float64), 1.0, atol=2e-6), (cat, idx)
                assert j.max() < n_joints
                for row_j, row_w in zip(j, w):
                    used = row_j[row_w > 0]
                    assert len(set(used.tolist())) == len(used), (cat, idx, row_j, row_w)
                if cat == "robot_prop":
                    assert np.all(w[:, 0] == 1.0), "props are rigid"


def test_inverse_bind_matrices_invert_joint_world_matrices():
    for cat, idx, data in samples():
        doc, binary = read_glb(data)
        skin = doc["skins"][0]
        ibm = read_accessor(doc, binary, skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
        world = world_matrices(doc)
        assert len(ibm) == len(skin["joints"])
        for k, j in enumerate(skin["joints"]):
            prod = world[j] @ ibm[k].astype(np.float64)
            assert np.allclose(prod, np.eye(4), atol=1e-4), (cat, idx, k, prod)
            assert np.array_equal(ibm[k][3], [0, 0, 0, 1])


def test_joint_positions_and_hierarchy_match_the_rig():
    for cat, idx, data in samples():
        rng = character_rng(SEED, idx)
        pick_category(rng)
        rig = BUILDERS[cat](rng)
        doc, _ = read_glb(data)
        world = world_matrices(doc)
        by_name = {doc["nodes"][j].get("name"): j for j in doc["skins"][0]["joints"]}
        assert len(by_name) == len(rig), "joint names are unique"
        parents = joint_parents(doc)
        for name, head, p in zip(rig.names, rig.heads, rig.parents):
            j = by_name[name]
            assert np.allclose(world[j][:3, 3], head, atol=1e-5 * rig.extent() + 1e-6), (cat, name)
            want = by_name[rig.names[p]] if p >= 0 else None
            assert parents[j] == want, (cat, name)


def test_bind_pose_is_displayed_upright_in_metres():
    """Skinned vertices are stored in world space: skinning them at bind pose is a no-op,
    whatever scale/rotation the armature carries, and characters stand on y ≈ 0."""
    for cat, idx, data in samples():
        doc, binary = read_glb(data)
        skin = doc["skins"][0]
        ibm = read_accessor(doc, binary, skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
        world = world_matrices(doc)
        mats = np.array([world[j] @ ibm[k] for k, j in enumerate(skin["joints"])])
        lo = np.full(3, np.inf)
        hi = -lo
        for n in doc["nodes"]:
            if "skin" not in n:
                continue
            for p in doc["meshes"][n["mesh"]]["primitives"]:
                pos = read_accessor(doc, binary, p["attributes"]["POSITION"]).astype(np.float64)
                j = read_accessor(doc, binary, p["attributes"]["JOINTS_0"]).astype(np.int64)
                w = read_accessor(doc, binary, p["attributes"]["WEIGHTS_0"]).astype(np.float64)
                h = np.c_[pos, np.ones(len(pos))]
                out = sum(w[:, k:k + 1] * np.einsum("vij,vj->vi", mats[j[:, k]], h) for k in range(4))
                scale = np.abs(pos).max() + 1e-9
                assert np.allclose(out[:, :3], pos, atol=1e-4 * scale), (cat, idx)
                lo, hi = np.minimum(lo, pos.min(0)), np.maximum(hi, pos.max(0))
        if cat == "humanoid":
            assert 0.9 < hi[1] - lo[1] < 3.0, (idx, lo, hi)  # roughly 1.2–2 m tall plus hats
            assert abs(lo[1]) < 0.1, "feet on the ground"


def test_mixamo_humanoids_follow_the_template():
    found = 0
    for idx in range(25):
        data, cat, info = make_character(SEED, 5000 + idx, "humanoid")
        if not info["kind"].endswith("mixamo"):
            continue
        doc, _ = read_glb(data)
        names = {j: doc["nodes"][j]["name"] for j in doc["skins"][0]["joints"]}
        base = {j: n.split(":", 1)[-1] for j, n in names.items()}
        inv = {b: j for j, b in base.items()}
        parents = joint_parents(doc)
        for child, par in MIXAMO_PARENTS.items():
            assert child in inv and par in inv, (idx, child)
            assert parents[inv[child]] == inv[par], (idx, child)
        assert parents[inv["Hips"]] is None or base[parents[inv["Hips"]]] not in MIXAMO_PARENTS
        found += 1
    assert found >= 8, "most humanoids use Mixamo names"


def test_sizes_in_range():
    for cat, idx, data in samples():
        doc, binary = read_glb(data)
        bones = len(doc["skins"][0]["joints"])
        assert 1 <= bones <= 80, (cat, bones)
    for i in range(40):
        _, cat, info = make_character(SEED + 1, i)
        assert 1 <= info["bones"] <= 80
        assert 150 <= info["vertices"] <= 12000, (cat, info)


def test_deterministic_for_a_seed():
    a = make_character(SEED, 7)[0]
    b = make_character(SEED, 7)[0]
    c = make_character(SEED + 1, 7)[0]
    assert a == b
    assert a != c


def test_cli_writes_files_and_manifest():
    d = tempfile.mkdtemp(prefix="synth_test_")
    try:
        assert main(["--out", d, "--count", "12", "--seed", "5", "--workers", "2", "--quiet"]) == 0
        lines = open(os.path.join(d, "manifest.tsv")).read().splitlines()
        assert lines[0] == "file\tsplit\tcategory"
        rows = [l.split("\t") for l in lines[1:]]
        assert len(rows) == 12
        for f, split, cat in rows:
            assert split == "train" and cat in CATEGORIES
            assert os.path.getsize(os.path.join(d, f)) > 0
        assert [r[0] for r in rows] == [file_name(5, i) for i in range(12)]
        # Same bytes in a single process: worker count does not change the output.
        d2 = tempfile.mkdtemp(prefix="synth_test_")
        try:
            main(["--out", d2, "--count", "3", "--seed", "5", "--workers", "1", "--quiet"])
            for i in range(3):
                assert open(os.path.join(d, file_name(5, i)), "rb").read() == open(os.path.join(d2, file_name(5, i)), "rb").read()
        finally:
            shutil.rmtree(d2)
    finally:
        shutil.rmtree(d)


def test_cli_balanced_gives_every_category_an_equal_share():
    d = tempfile.mkdtemp(prefix="synth_test_")
    try:
        n = 2 * len(CATEGORIES)
        assert main(["--out", d, "--count", str(n), "--seed", "9", "--start", "3",
                     "--balanced", "--workers", "1", "--quiet"]) == 0
        rows = [l.split("\t") for l in open(os.path.join(d, "manifest.tsv")).read().splitlines()[1:]]
        cats = [r[2] for r in rows]
        assert sorted(cats) == sorted(CATEGORIES * 2), cats
        # The manifest's category is what the builder made: the file holds that rig.
        assert make_character(9, 3, cats[0])[0] == open(os.path.join(d, rows[0][0]), "rb").read()
        try:
            main(["--out", d, "--count", "1", "--balanced", "--category", "humanoid"])
            raise AssertionError("--balanced with --category was accepted")
        except SystemExit as e:
            assert e.code == 2
    finally:
        shutil.rmtree(d)


def test_rigserve_reads_them():
    """When the rigserve binary is built, its loader must read every file and find the
    same joints. Skipped (passes) when it is not built."""
    root = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
    exe = os.path.join(root, "target", "release", "rigserve")
    if not os.path.exists(exe):
        print("skipped: target/release/rigserve not built")
        return
    d = tempfile.mkdtemp(prefix="synth_rs_")
    try:
        for cat, idx, data in samples()[::PER_CATEGORY]:
            path = os.path.join(d, f"{cat}.glb")
            open(path, "wb").write(data)
            r = subprocess.run([exe, "inspect", "--json", path], capture_output=True, text=True, timeout=60)
            assert r.returncode == 0, (cat, r.stderr)
            bones = json.loads(r.stdout)["bones"]
            rng = character_rng(SEED, idx)
            pick_category(rng)
            rig = BUILDERS[cat](rng)
            got = {b["name"]: np.array(b["head"]) for b in bones}
            assert set(got) == set(rig.names), cat
            for name, head in zip(rig.names, rig.heads):
                assert np.allclose(got[name], head, atol=1e-4 * rig.extent()), (cat, name)
    finally:
        shutil.rmtree(d)


def _run_all() -> int:
    failed = 0
    tests = [(k, v) for k, v in sorted(globals().items()) if k.startswith("test_") and callable(v)]
    for name, fn in tests:
        try:
            fn()
            print(f"ok   {name}")
        except Exception as e:  # noqa: BLE001 - report every failure, then exit non-zero
            failed += 1
            print(f"FAIL {name}: {type(e).__name__}: {e}")
    print(f"{len(tests) - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(_run_all())
