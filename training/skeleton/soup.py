"""Averages the weights of skeleton checkpoints that share an architecture (a "model soup").

    python3 -m training.skeleton.soup --ckpt a/last.pt --ckpt b/last.pt --out soup.pt

Fine-tunes that start from the same weights stay in one basin of the loss, so their mean
is itself a model, and often one that generalises better than each (Wortsman et al.,
2022). The output is a checkpoint `export.py` and `check_export.py` read like any other.
"""

from __future__ import annotations

import argparse

import torch


def average(states: list[dict]) -> dict:
    """The element-wise mean of state dicts with the same keys and shapes."""
    keys = states[0].keys()
    for s in states[1:]:
        if s.keys() != keys:
            raise ValueError("checkpoints hold different parameters")
    out = {}
    for k in keys:
        ts = [s[k] for s in states]
        if any(t.shape != ts[0].shape for t in ts):
            raise ValueError(f"{k}: shapes differ")
        out[k] = torch.stack([t.float() for t in ts]).mean(0).to(ts[0].dtype) if ts[0].is_floating_point() else ts[0]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ckpt", action="append", required=True, help="checkpoint from train.py (repeat, two or more)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if len(a.ckpt) < 2:
        ap.error("give at least two --ckpt")
    cks = [torch.load(p, map_location="cpu", weights_only=False) for p in a.ckpt]
    if any(c["config"] != cks[0]["config"] for c in cks[1:]):
        raise SystemExit("soup: checkpoints have different model configs")
    torch.save({"config": cks[0]["config"], "model": average([c["model"] for c in cks]), "step": 0,
                "soup": list(a.ckpt)}, a.out)
    print(f"[soup] {len(cks)} checkpoints -> {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
