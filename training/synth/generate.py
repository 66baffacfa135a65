"""Procedural rigged characters for training volume.

    python3 -m training.synth.generate --out DIR --count N --seed S [--workers 2] [--balanced]

Writes N GLB files and DIR/manifest.tsv (`file`, `split`, `category`), the layout
`rigserve dataset --input DIR` reads. Character i depends only on (seed, i), so output is
identical whatever the worker count, and a run can be extended or regenerated in parts.
`--balanced` gives every category the same share (character i is category i mod 8), for
fine-tuning legs aimed at the kinds the default mix draws least.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from multiprocessing import Pool

import numpy as np

from .assemble import encode
from .creatures import bird_flyer, fish_snake_tail, insect_spider, other_creature, quadruped
from .humanoid import humanoid, humanoid_creature
from .props import robot_prop

# The mix asked for; humanoids dominate real data and what users upload.
CATEGORY_MIX = {
    "humanoid": 0.25,
    "quadruped": 0.18,
    "fish_snake_tail": 0.12,
    "robot_prop": 0.12,
    "other_creature": 0.10,
    "humanoid_creature": 0.10,
    "bird_flyer": 0.07,
    "insect_spider": 0.06,
}
BUILDERS = {
    "humanoid": humanoid,
    "humanoid_creature": humanoid_creature,
    "quadruped": quadruped,
    "bird_flyer": bird_flyer,
    "insect_spider": insect_spider,
    "fish_snake_tail": fish_snake_tail,
    "other_creature": other_creature,
    "robot_prop": robot_prop,
}
CATEGORIES = list(CATEGORY_MIX)


def character_rng(seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, index]))


def pick_category(rng: np.random.Generator) -> str:
    p = np.array([CATEGORY_MIX[c] for c in CATEGORIES])
    return CATEGORIES[int(rng.choice(len(CATEGORIES), p=p / p.sum()))]


def balanced_category(index: int) -> str:
    """Round-robin over the categories: any run of 8 consecutive indices holds each once."""
    return CATEGORIES[index % len(CATEGORIES)]


def make_character(seed: int, index: int, category: str | None = None):
    """(glb bytes, category, info) for character `index` of `seed`."""
    rng = character_rng(seed, index)
    cat = pick_category(rng)
    if category is not None:
        cat = category
    rig = BUILDERS[cat](rng)
    assert rig.category == cat, (rig.category, cat)
    data, info = encode(rig, rng)
    return data, cat, info


def file_name(seed: int, index: int) -> str:
    return f"synth_s{seed}_{index:06d}.glb"


def _work(args):
    out, seed, index, category = args
    data, cat, info = make_character(seed, index, category)
    name = file_name(seed, index)
    with open(os.path.join(out, name), "wb") as f:
        f.write(data)
    return index, name, cat, info


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--count", type=int, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--start", type=int, default=0, help="first character index (to extend a set)")
    ap.add_argument("--workers", type=int, default=2, help="processes (the build machine has 2 cores)")
    ap.add_argument("--category", choices=CATEGORIES, help="only this category (for inspection)")
    ap.add_argument("--balanced", action="store_true",
                    help="equal shares of every category instead of the default mix")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    if a.balanced and a.category:
        ap.error("--balanced and --category exclude each other")
    os.makedirs(a.out, exist_ok=True)
    jobs = [(a.out, a.seed, i, balanced_category(i) if a.balanced else a.category)
            for i in range(a.start, a.start + a.count)]
    t0 = time.time()
    rows = []
    if a.workers <= 1:
        results = map(_work, jobs)
        pool = None
    else:
        pool = Pool(min(a.workers, 2 if a.workers >= 2 else 1))
        results = pool.imap_unordered(_work, jobs, chunksize=8)
    try:
        for k, r in enumerate(results, 1):
            rows.append(r)
            if not a.quiet and (k % 500 == 0 or k == len(jobs)):
                dt = time.time() - t0
                print(f"{k}/{len(jobs)} characters, {k / dt:.1f}/s", file=sys.stderr)
    finally:
        if pool is not None:
            pool.close()
            pool.join()
    rows.sort()
    with open(os.path.join(a.out, "manifest.tsv"), "w") as f:
        f.write("file\tsplit\tcategory\n")
        for _, name, cat, _ in rows:
            f.write(f"{name}\ttrain\t{cat}\n")
    if not a.quiet:
        counts = {}
        for _, _, cat, _ in rows:
            counts[cat] = counts.get(cat, 0) + 1
        verts = [r[3]["vertices"] for r in rows]
        bones = [r[3]["bones"] for r in rows]
        print(f"wrote {len(rows)} files in {time.time() - t0:.1f}s; categories {counts}; "
              f"vertices {min(verts)}..{max(verts)} (median {int(np.median(verts))}); "
              f"bones {min(bones)}..{max(bones)} (median {int(np.median(bones))})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
