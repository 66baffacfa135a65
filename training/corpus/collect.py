"""Rebuild the real-rig corpus from git mirrors.

    python3 -m training.corpus.collect --manifest training/corpus/manifest.tsv \
        --mirrors /work/.mirror --out ../corpus

Each manifest row names repo, commit and path inside the mirror
`<mirrors>/<owner>+<name>/repo` (a bare git dir). The file is taken out of git at that
commit (with the files a .gltf references), turned into GLB (copy for .glb/.vrm, repack
for .gltf, assimp for .b3d/.x/.dae/..., Blender for .fbx/.blend), weights renormalised
where their sums stray, and checked: >= 2 joints, every skinned vertex weighted, weights
summing to 1 within 1e-3, a finite bind pose near the mesh. Rows that fail are listed in
<out>/DROPPED.tsv with the reason. <out> gets manifest.tsv (the ../shared/rigs layout,
split `train` for every row), ARTISTS.tsv (file, artist) and GROUPS.tsv (file, group)."""
import argparse
import hashlib
import os
import posixpath
import re
import subprocess
import sys
import tempfile

from . import convert, glb

OUT_COLS = ["file", "split", "category", "joints", "skinned_vertices", "rigid", "source_repo",
            "source_path", "license", "format"]
MANIFEST_COLS = ["repo", "commit", "path", "licence", "artist", "category", "format", "joints",
                 "skinned_vertices", "heldout_check", "group"]


def read_tsv(path):
    lines = [l.rstrip("\n").rstrip("\r") for l in open(path, encoding="utf-8")]
    head = lines[0].split("\t")
    return head, [dict(zip(head, l.split("\t"))) for l in lines[1:] if l.strip()]


def git_dir(mirrors, repo):
    """The bare git dir of a mirror: <mirrors>/<owner>+<name>/repo, or repo/.git where the
    snapshot arrived as a work tree."""
    gd = os.path.join(mirrors, repo.replace("/", "+"), "repo")
    return os.path.join(gd, ".git") if os.path.isdir(os.path.join(gd, ".git")) else gd


def git_show(gd, commit, path):
    r = subprocess.run(["git", "--git-dir", gd, "show", f"{commit}:{path}"], capture_output=True)
    if r.returncode != 0:
        raise FileNotFoundError(f"{path} not in {gd}@{commit[:10]}: {r.stderr.decode(errors='replace').strip()[:120]}")
    return r.stdout


def out_name(repo, path, taken):
    stem = posixpath.splitext(posixpath.basename(path))[0]
    base = re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{repo.split('/')[1]}__{stem}")[:90]
    name = base + ".glb"
    if name in taken:
        name = f"{base}_{hashlib.sha1((repo + ':' + path).encode()).hexdigest()[:8]}.glb"
    taken.add(name)
    return name


def build_one(mirrors, repo, commit, path, out_path, work):
    """Take repo:path@commit out of its mirror, convert to GLB at out_path, renormalise and
    check. Returns (stats, tool, problems); problems empty when the file is usable."""
    gd = git_dir(mirrors, repo)
    if not os.path.isdir(gd):
        return None, None, [f"no mirror {gd}"]
    data = git_show(gd, commit, path)
    ext = posixpath.splitext(path)[1].lower()
    src = os.path.join(work, "src" + ext)
    open(src, "wb").write(data)
    base = posixpath.dirname(path)
    read_rel = lambda uri: git_show(gd, commit, posixpath.normpath(posixpath.join(base, uri)))
    tmp = os.path.join(work, "conv.glb")
    if os.path.exists(tmp):
        os.unlink(tmp)
    try:
        tool = convert.to_glb(src, tmp, read_rel)
    except Exception as e:  # converter failure is a reason, not a crash
        return None, None, [f"conversion failed: {e}"]
    try:
        doc, bin_ = glb.load_any(tmp)
        doc, bin_, _ = glb.renormalise_weights(doc, bin_)
        stats = glb.rig_stats(doc, bin_)
    except Exception as e:
        return None, tool, [f"unreadable result: {type(e).__name__}: {e}"]
    problems = glb.rig_problems(stats)
    if not problems:
        open(out_path, "wb").write(glb.write_glb(doc, bin_))
    return stats, tool, problems



FORMAT_NOTE = {"copy": "glb (copied{src})", "repack": "glb (repacked from .gltf)",
               "assimp": "glb (converted from {src} with assimp)", "blender": "glb (converted from {src} with Blender)"}


def fmt_note(tool, ext):
    if tool == "copy":
        return "glb (copied)" if ext == ".glb" else f"glb (copied from {ext})"
    return FORMAT_NOTE[tool].format(src=ext)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--manifest", required=True)
    ap.add_argument("--mirrors", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    head, rows = read_tsv(a.manifest)
    if head != MANIFEST_COLS:
        sys.exit(f"{a.manifest}: header must be {MANIFEST_COLS}")
    os.makedirs(a.out, exist_ok=True)
    taken, out_rows, dropped = set(), [], []
    with tempfile.TemporaryDirectory() as work:
        for i, r in enumerate(rows):
            name = out_name(r["repo"], r["path"], taken)
            dest = os.path.join(a.out, name)
            try:
                stats, tool, problems = build_one(a.mirrors, r["repo"], r["commit"], r["path"], dest, work)
            except FileNotFoundError as e:
                stats, tool, problems = None, None, [str(e)]
            if problems:
                dropped.append((name, r["repo"], r["path"], "; ".join(problems)))
                if os.path.exists(dest):
                    os.unlink(dest)
                if not a.quiet:
                    print(f"[{i + 1}/{len(rows)}] DROP {r['repo']}:{r['path']}: {'; '.join(problems)}", flush=True)
                continue
            if str(len(stats["joints"])) != r["joints"] and not a.quiet:
                print(f"  note: {name} has {len(stats['joints'])} joints, manifest says {r['joints']}")
            ext = posixpath.splitext(r["path"])[1].lower()
            out_rows.append({"file": name, "split": "train", "category": r["category"],
                             "joints": str(len(stats["joints"])), "skinned_vertices": str(stats["skinned_vertices"]),
                             "rigid": "yes" if stats["rigid_vertices"] else "no", "source_repo": r["repo"],
                             "source_path": r["path"], "license": r["licence"], "format": fmt_note(tool, ext),
                             "_artist": r["artist"], "_group": r["group"]})
            if not a.quiet:
                print(f"[{i + 1}/{len(rows)}] ok {name} ({len(stats['joints'])} joints)", flush=True)
    # Every row is train; groups therefore never straddle splits.
    with open(os.path.join(a.out, "manifest.tsv"), "w", encoding="utf-8") as f:
        f.write("\t".join(OUT_COLS) + "\n")
        for o in out_rows:
            f.write("\t".join(o[c] for c in OUT_COLS) + "\n")
    with open(os.path.join(a.out, "ARTISTS.tsv"), "w", encoding="utf-8") as f:
        f.write("file\tartist\n")
        for o in out_rows:
            f.write(f"{o['file']}\t{o['_artist']}\n")
    with open(os.path.join(a.out, "GROUPS.tsv"), "w", encoding="utf-8") as f:
        f.write("file\tgroup\n")
        for o in out_rows:
            f.write(f"{o['file']}\t{o['_group']}\n")
    with open(os.path.join(a.out, "DROPPED.tsv"), "w", encoding="utf-8") as f:
        f.write("file\trepo\tpath\treason\n")
        for d in dropped:
            f.write("\t".join(d) + "\n")
    print(f"{len(out_rows)} rigs written to {a.out}, {len(dropped)} dropped (DROPPED.tsv)")
    return 0 if out_rows or not rows else 1


if __name__ == "__main__":
    sys.exit(main())
