"""Markdown tables of skin figures from `rigserve eval` reports, side by side.

    python3 bench/skin_table.py learned=/tmp/learned.json geometric=/tmp/geo.json [blender=/tmp/bh.json]
"""

import json
import sys

COLS = ["l1", "precision", "recall", "deformation"]


def fmt(k, v):
    return "—" if v is None else (f"{v:.4f}" if k in ("l1", "deformation") else f"{v:.3f}")


def main(args):
    reports = [(name, json.load(open(path))) for name, path in (a.split("=", 1) for a in args)]
    cats = sorted({c for _, r in reports for c in r["per_category"]})
    print("| category | files | " + " | ".join(f"{n} {c}" for c in COLS for n, _ in reports) + " |")
    print("|---|---|" + "---|" * (len(COLS) * len(reports)))
    rows = [(c, lambda r, c=c: r["per_category"].get(c)) for c in cats] + [("**overall**", lambda r: r["overall"])]
    for label, get in rows:
        first = get(reports[0][1]) or {}
        cells = []
        for c in COLS:
            for _, r in reports:
                s = (get(r) or {}).get("skin") or {}
                cells.append(fmt(c, s.get(c)))
        print(f"| {label} | {first.get('count', '')} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
