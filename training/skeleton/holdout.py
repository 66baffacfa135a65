"""Splits the `train` rigs of ../shared/rigs into `train` and `hold` for a held-out model.

    python3 -m training.skeleton.holdout --rigs ../shared/rigs --out /tmp/rig_hold

The shipped skeleton model has seen every `train` rig, so `train` cannot judge choices
that involve the model (how to pick among its candidates and the library's): it favours
the model there. `dev` is the only real set it has not seen, and dev must not choose. A
model trained without a quarter of `train` (the `hold` rows) makes those a second real,
unseen set to choose on: `rigserve eval --dataset OUT --split hold --models HELD_OUT …`.

Writes OUT/manifest.tsv (the `train` rows only, a quarter of each category relabelled
`hold`: per category sorted by file name, every fourth from the third; `--part K` starts
from the (K+1)-th instead, so parts 0-3 are four disjoint held-out quarters) and a symbolic
link per file to the rigs folder, so the third-party files are never copied. The split
is a pure function of the manifest and the part, so every session draws the same one.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter, defaultdict


def hold_rows(rows: list[dict], part: int = 2) -> set[str]:
    """Names of the `train` rows that go to `hold`: per category, every fourth from index
    `part` (2 is the split the first held-out models used)."""
    by_cat = defaultdict(list)
    for r in rows:
        if r["split"] == "train":
            by_cat[r["category"]].append(r["file"])
    return {f for files in by_cat.values() for k, f in enumerate(sorted(files)) if k % 4 == part}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rigs", default="../shared/rigs", help="folder with manifest.tsv and the GLBs")
    ap.add_argument("--out", required=True)
    ap.add_argument("--part", type=int, default=2, choices=range(4),
                    help="which quarter of each category to hold out (default 2, the first split)")
    a = ap.parse_args(argv)
    src = os.path.abspath(a.rigs)
    with open(os.path.join(src, "manifest.tsv"), encoding="utf-8") as f:
        lines = [l.rstrip("\n").split("\t") for l in f if l.strip()]
    header, body = lines[0], lines[1:]
    rows = [dict(zip(header, r)) for r in body]
    hold = hold_rows(rows, a.part)
    os.makedirs(a.out, exist_ok=True)
    split_col = header.index("split")
    out = ["\t".join(header)]
    for cells, r in zip(body, rows):
        if r["split"] != "train":
            continue
        cells = list(cells)
        cells[split_col] = "hold" if r["file"] in hold else "train"
        out.append("\t".join(cells))
        link = os.path.join(a.out, r["file"])
        if not os.path.lexists(link):
            os.symlink(os.path.join(src, r["file"]), link)
    with open(os.path.join(a.out, "manifest.tsv"), "w", encoding="utf-8") as f:
        f.write("\n".join(out) + "\n")
    counts = Counter(r["category"] for r in rows if r["file"] in hold)
    print(f"{len(hold)} of {sum(r['split'] == 'train' for r in rows)} train rigs held out: {dict(sorted(counts.items()))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
