"""Tests of holdout.py (standard library only): python3 -m training.skeleton.test_holdout"""

from __future__ import annotations

import os
import tempfile
import unittest

from .holdout import hold_rows, main


class HoldoutTest(unittest.TestCase):
    def test_a_quarter_of_each_category_by_name(self):
        rows = [{"file": f"h{i:02d}.glb", "split": "train", "category": "humanoid"} for i in range(8)]
        rows += [{"file": "q0.glb", "split": "train", "category": "quadruped"},
                 {"file": "d0.glb", "split": "dev", "category": "humanoid"}]
        self.assertEqual(hold_rows(rows), {"h02.glb", "h06.glb"})
        self.assertEqual(hold_rows(list(reversed(rows))), {"h02.glb", "h06.glb"})

    def test_the_four_parts_are_disjoint_and_cover_train(self):
        rows = [{"file": f"{c}{i:02d}.glb", "split": "train", "category": c}
                for c in ("a", "b") for i in range(7)]
        parts = [hold_rows(rows, k) for k in range(4)]
        self.assertEqual(parts[0], {"a00.glb", "a04.glb", "b00.glb", "b04.glb"})
        self.assertEqual(set().union(*parts), {r["file"] for r in rows})
        self.assertEqual(sum(len(p) for p in parts), len(rows))

    def test_writes_links_and_only_train_rows(self):
        with tempfile.TemporaryDirectory() as d:
            rigs, out = os.path.join(d, "rigs"), os.path.join(d, "out")
            os.makedirs(rigs)
            lines = ["file\tsplit\tcategory\tlicense"]
            for i in range(4):
                lines.append(f"f{i}.glb\ttrain\tfish\tCC0")
            lines.append("g.glb\tdev\tfish\tCC0")
            for name in ["f0.glb", "f1.glb", "f2.glb", "f3.glb", "g.glb"]:
                open(os.path.join(rigs, name), "wb").close()
            with open(os.path.join(rigs, "manifest.tsv"), "w") as f:
                f.write("\n".join(lines) + "\n")
            self.assertEqual(main(["--rigs", rigs, "--out", out]), 0)
            with open(os.path.join(out, "manifest.tsv")) as f:
                got = [l.rstrip("\n").split("\t") for l in f]
            self.assertEqual(got[0], ["file", "split", "category", "license"])
            self.assertEqual([r[:2] for r in got[1:]],
                             [["f0.glb", "train"], ["f1.glb", "train"], ["f2.glb", "hold"], ["f3.glb", "train"]])
            self.assertTrue(os.path.islink(os.path.join(out, "f2.glb")))
            self.assertFalse(os.path.lexists(os.path.join(out, "g.glb")))


if __name__ == "__main__":
    unittest.main()
