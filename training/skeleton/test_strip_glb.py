"""`strip_glb` keeps what `rigserve dataset` reads, exactly or to 1/65535 for weights.

    python -m training.skeleton.test_strip_glb
"""

from __future__ import annotations

import os
import tempfile

import numpy as np

from training.synth.generate import make_character
from training.synth.glb import read_glb

from .strip_glb import strip, values


def _prim_arrays(doc, binary):
    out = []
    for m in doc["meshes"]:
        for p in m["primitives"]:
            a = {k: values(doc, binary, v) for k, v in p["attributes"].items()}
            a["indices"] = values(doc, binary, p["indices"]).reshape(-1)
            out.append(a)
    return out


def test_strip_keeps_geometry_skin_and_drops_the_rest():
    data, _, _ = make_character(5, 3)
    d = tempfile.mkdtemp(prefix="strip_")
    src, dst = os.path.join(d, "in.glb"), os.path.join(d, "out.glb")
    open(src, "wb").write(data)
    strip(src, dst)
    before, after = read_glb(open(src, "rb").read()), read_glb(open(dst, "rb").read())
    assert os.path.getsize(dst) < os.path.getsize(src)
    assert after[0]["nodes"] == before[0]["nodes"]
    assert [s["joints"] for s in after[0]["skins"]] == [s["joints"] for s in before[0]["skins"]]
    for s0, s1 in zip(before[0]["skins"], after[0]["skins"]):
        if "inverseBindMatrices" in s0:
            np.testing.assert_array_equal(values(*before, s0["inverseBindMatrices"]),
                                          values(*after, s1["inverseBindMatrices"]))
    for p0, p1 in zip(_prim_arrays(*before), _prim_arrays(*after)):
        assert set(p1) == {"POSITION", "JOINTS_0", "WEIGHTS_0", "indices"} & set(p0) | {"indices"}
        np.testing.assert_array_equal(p0["POSITION"], p1["POSITION"])
        np.testing.assert_array_equal(p0["indices"], p1["indices"])
        np.testing.assert_array_equal(p0["JOINTS_0"], p1["JOINTS_0"])
        assert np.abs(p0["WEIGHTS_0"] - p1["WEIGHTS_0"]).max() <= 0.5 / 65535 + 1e-7
    for key in ("animations", "materials", "textures", "images"):
        assert key not in after[0]


if __name__ == "__main__":
    from training.testing import run_tests

    run_tests(globals())
