"""Build training/corpus/manifest.tsv and REJECTED.tsv from the sources in sources.py.

    python3 -m training.corpus.survey [--mirrors /work/.mirror] [--only OWNER/NAME]

For every source repository (its mirror must exist) it lists model files, converts each
with the collector's code into a cache folder, runs the held-out check on the result
(`../shared/heldout/check.py FILE --repo OWNER/NAME`), drops copies of ../shared/rigs and
exact or forked duplicates, assigns near-duplicate groups, applies the 15% artist cap and
writes the manifest. Results per blob are cached in --cache so reruns are quick."""
import argparse
import hashlib
import importlib.util
import json
import os
import re
import subprocess
import sys
from collections import Counter, defaultdict

from . import collect, sources

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SHARED = os.path.normpath(os.path.join(ROOT, "..", "shared"))
CHECK = os.path.join(SHARED, "heldout", "check.py")
MODEL_EXT = (".b3d", ".x", ".glb", ".gltf", ".vrm", ".fbx", ".dae", ".md5mesh", ".iqm", ".smd", ".ms3d", ".blend")
ARTIST_CAP = 0.15


def _check_mod():
    spec = importlib.util.spec_from_file_location("heldout_check", CHECK)
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


def ls_tree(gd):
    out = subprocess.run(["git", "--git-dir", gd, "ls-tree", "-r", "-l", "HEAD"], capture_output=True, text=True).stdout
    for line in out.splitlines():
        meta, path = line.split("\t", 1)
        _, kind, sha, size = meta.split()
        if kind == "blob":
            yield path, sha, (int(size) if size.isdigit() else 0)


def heldout(paths, repo):
    """{path: 'clear' | reason} from check.py, plus the repo verdict."""
    res = {}
    r = subprocess.run([sys.executable, CHECK, *paths, "--repo", repo], capture_output=True, text=True)
    repo_ok = True
    for line in r.stdout.splitlines():
        if line.startswith("HELD OUT  repo"):
            repo_ok = False
        for p in paths:
            if p in line:
                res[p] = "clear" if line.startswith("clear") else line.replace(p, os.path.basename(p)).strip()
    return repo_ok, res


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--mirrors", default="/work/.mirror")
    ap.add_argument("--cache", default="/tmp/corpus_survey")
    ap.add_argument("--only", default=None)
    ap.add_argument("--manifest", default=os.path.join(HERE, "manifest.tsv"))
    ap.add_argument("--rejected", default=os.path.join(HERE, "REJECTED.tsv"))
    a = ap.parse_args(argv)
    os.makedirs(a.cache, exist_ok=True)
    chk = _check_mod()
    salt = "corpus-dedupe"
    # signatures of ../shared/rigs (train and dev): a copy of one is not a new rig
    shared_sigs = []
    sdir = os.path.join(SHARED, "rigs")
    sig_cache = os.path.join(a.cache, "shared_sigs.json")
    if os.path.exists(sig_cache):
        shared_sigs = json.load(open(sig_cache))
    else:
        for f in sorted(os.listdir(sdir)):
            if f.endswith(".glb"):
                try:
                    shared_sigs.append([f, chk.signature(salt, os.path.join(sdir, f))])
                except Exception:
                    pass
        json.dump(shared_sigs, open(sig_cache, "w"))
    rows, rejected = [], []
    seen_blob = {}
    kept_sigs = []  # (repo, path, sig, group)
    groups = {}
    for src in sources.SOURCES:
        repo = src["repo"]
        gd = collect.git_dir(a.mirrors, repo)
        if not os.path.isdir(gd):
            print(f"-- {repo}: no mirror, skipped")
            continue
        rr = subprocess.run([sys.executable, CHECK, "--repo", repo], capture_output=True, text=True)
        if "HELD OUT" in rr.stdout:
            print(f"-- {repo}: HELD OUT repository, nothing taken")
            rejected.append((repo, "*", "HELD OUT", "repository is one an evaluation set came from; nothing taken"))
            continue
        commit = subprocess.run(["git", "--git-dir", gd, "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
        files = [(p, s, z) for p, s, z in ls_tree(gd) if p.lower().endswith(MODEL_EXT)]
        inc = re.compile(src.get("include", ".*"), re.I)
        exc = re.compile(src["exclude"], re.I) if src.get("exclude") else None
        allow_ext = tuple(src.get("ext", (".b3d", ".x", ".glb", ".gltf", ".vrm", ".fbx", ".dae", ".md5mesh", ".iqm", ".smd")))
        cand = []
        for p, sha, size in sorted(files):
            if not p.lower().endswith(allow_ext) or not inc.search(p) or (exc and exc.search(p)):
                continue
            cand.append((p, sha, size))
        print(f"-- {repo} @ {commit[:10]}: {len(cand)} candidate files", flush=True)
        results = []
        for p, sha, size in cand:
            lic, artist = sources.licence_artist(src, p)
            if sha in seen_blob:
                rejected.append((repo, p, "duplicate", f"same file as {seen_blob[sha]}"))
                continue
            seen_blob[sha] = f"{repo}:{p}"
            if lic is None:
                rejected.append((repo, p, "licence", "no stated licence for this file"))
                continue
            if not sources.permissive(lic):
                rejected.append((repo, p, "licence", f"not permissive: {lic}"))
                continue
            cdir = os.path.join(a.cache, sha[:2])
            os.makedirs(cdir, exist_ok=True)
            glb_path = os.path.join(cdir, sha + ".glb")
            meta_path = os.path.join(cdir, sha + ".json")
            if os.path.exists(meta_path):
                meta = json.load(open(meta_path))
            else:
                wd = os.path.join(a.cache, "work")
                os.makedirs(wd, exist_ok=True)
                try:
                    stats, tool, problems = collect.build_one(a.mirrors, repo, commit, p, glb_path, wd)
                except Exception as e:
                    stats, tool, problems = None, None, [f"{type(e).__name__}: {e}"]
                meta = {"tool": tool, "problems": problems,
                        "joints": len(stats["joints"]) if stats else 0,
                        "names": stats["names"] if stats else [],
                        "skinned_vertices": stats["skinned_vertices"] if stats else 0}
                json.dump(meta, open(meta_path, "w"))
            if meta["problems"]:
                rejected.append((repo, p, "conversion/check", "; ".join(meta["problems"])[:300]))
                continue
            results.append((p, sha, lic, artist, meta, glb_path))
        if not results:
            continue
        repo_ok, verdict = heldout([r[5] for r in results], repo)
        if not repo_ok:
            for r in results:
                rejected.append((repo, r[0], "HELD OUT", "repository is one an evaluation set came from"))
            continue
        for p, sha, lic, artist, meta, glb_path in results:
            v = verdict.get(glb_path, "no verdict")
            if v != "clear":
                rejected.append((repo, p, "HELD OUT", v))
                continue
            sig = chk.signature(salt, glb_path)
            dup = next((f for f, s in shared_sigs if chk.same_rig(sig, s)[1]), None)
            if dup:
                rejected.append((repo, p, "duplicate", f"a copy of ../shared/rigs/{dup}"))
                continue
            names_key = hashlib.sha1(("|".join(sorted(chk.norm(n) for n in meta["names"])) + f"#{meta['joints']}").encode()).hexdigest()[:10]
            gkey = (repo, names_key)
            grp = None
            fork = None
            for krepo, kpath, ksig, kgrp, kv in kept_sigs:
                if chk.same_rig(sig, ksig)[1]:
                    if krepo != repo and abs(kv - meta["skinned_vertices"]) <= 0.02 * max(kv, 1):
                        fork = f"{krepo}:{kpath}"
                        break
                    grp = grp or kgrp
            if fork:
                rejected.append((repo, p, "duplicate", f"same rig and mesh as {fork}"))
                continue
            grp = grp or groups.get(gkey) or f"g{len(set(groups.values())) + 1:04d}"
            groups[gkey] = grp
            kept_sigs.append((repo, p, sig, grp, meta["skinned_vertices"]))
            cat = sources.category(src, p)
            if cat is None:
                rejected.append((repo, p, "category", "no category rule matched; not a creature/character?"))
                continue
            rows.append({"repo": repo, "commit": commit, "path": p, "licence": lic, "artist": artist,
                         "category": cat, "format": p.rsplit(".", 1)[-1].lower(), "joints": str(meta["joints"]),
                         "skinned_vertices": str(meta["skinned_vertices"]), "heldout_check": "clear", "group": grp})
    # artist cap: no artist above 15% of rows; drop from the biggest, extra group members first
    while rows:
        cnt = Counter(r["artist"] for r in rows)
        artist, n = cnt.most_common(1)[0]
        if n <= ARTIST_CAP * len(rows):
            break
        gsize = Counter(r["group"] for r in rows)
        mine = [i for i, r in enumerate(rows) if r["artist"] == artist]
        i = max(mine, key=lambda i: (gsize[rows[i]["group"]], i))
        r = rows.pop(i)
        rejected.append((r["repo"], r["path"], "artist cap", f"{artist} over {int(ARTIST_CAP * 100)}% of rows"))
    with open(a.manifest, "w", encoding="utf-8") as f:
        f.write("\t".join(collect.MANIFEST_COLS) + "\n")
        for r in rows:
            f.write("\t".join(r[c] for c in collect.MANIFEST_COLS) + "\n")
    with open(a.rejected, "w", encoding="utf-8") as f:
        f.write("repo\tpath\tkind\treason\n")
        for r in rejected:
            f.write("\t".join(x.replace("\t", " ") for x in r) + "\n")
    print(f"{len(rows)} rows, {len(set(r['artist'] for r in rows))} artists; {len(rejected)} rejected")
    print(Counter(r["category"] for r in rows).most_common())
    print(Counter(r["artist"] for r in rows).most_common(40))
    print(Counter(x[2] for x in rejected).most_common())


if __name__ == "__main__":
    main()
