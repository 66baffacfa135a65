"""Tests of soup.py (needs torch): python3 -m training.skeleton.test_soup"""

from __future__ import annotations

import os
import tempfile
import unittest

import torch

from .soup import average, main


class SoupTest(unittest.TestCase):
    def test_mean_of_floats_first_of_integers(self):
        a = {"w": torch.tensor([1.0, 2.0]), "n": torch.tensor(3)}
        b = {"w": torch.tensor([3.0, 6.0]), "n": torch.tensor(5)}
        out = average([a, b])
        self.assertTrue(torch.equal(out["w"], torch.tensor([2.0, 4.0])))
        self.assertEqual(int(out["n"]), 3)

    def test_refuses_different_parameters(self):
        with self.assertRaises(ValueError):
            average([{"w": torch.zeros(2)}, {"v": torch.zeros(2)}])
        with self.assertRaises(ValueError):
            average([{"w": torch.zeros(2)}, {"w": torch.zeros(3)}])

    def test_writes_a_checkpoint_and_refuses_other_configs(self):
        with tempfile.TemporaryDirectory() as d:
            paths = [os.path.join(d, f"{i}.pt") for i in range(3)]
            for i, p in enumerate(paths):
                cfg = {"d_model": 8 if i < 2 else 16}
                torch.save({"config": cfg, "model": {"w": torch.full((2,), float(i))}}, p)
            out = os.path.join(d, "soup.pt")
            self.assertEqual(main(["--ckpt", paths[0], "--ckpt", paths[1], "--out", out]), 0)
            ck = torch.load(out, weights_only=False)
            self.assertEqual(ck["config"], {"d_model": 8})
            self.assertTrue(torch.equal(ck["model"]["w"], torch.full((2,), 0.5)))
            with self.assertRaises(SystemExit):
                main(["--ckpt", paths[0], "--ckpt", paths[2], "--out", out])


if __name__ == "__main__":
    unittest.main()
