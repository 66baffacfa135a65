"""Turn one source model into a GLB: copy (glb/vrm), repack (gltf), assimp or Blender."""
import os
import shutil
import subprocess
import tempfile

from . import glb

ASSIMP_EXT = {".b3d", ".x", ".dae", ".md5mesh", ".iqm", ".smd", ".ms3d", ".3ds", ".md2", ".mdl", ".ogex", ".ply"}
BLENDER_EXT = {".fbx", ".blend"}

BLENDER_SCRIPT = r'''
import bpy, sys
src, out = sys.argv[-2], sys.argv[-1]
if src.lower().endswith(".blend"):
    bpy.ops.wm.open_mainfile(filepath=src)
else:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.fbx(filepath=src)
bpy.ops.export_scene.gltf(filepath=out, export_format="GLB", export_animations=False,
                          export_skins=True, export_morph=False, export_apply=False)
'''


def tool_for(ext):
    ext = ext.lower()
    if ext in (".glb", ".vrm"):
        return "copy"
    if ext == ".gltf":
        return "repack"
    if ext in BLENDER_EXT:
        return "blender"
    if ext in ASSIMP_EXT:
        return "assimp"
    return None


def assimp(src, out, timeout=300):
    r = subprocess.run(["assimp", "export", src, out, "-f", "glb2"], capture_output=True, text=True, timeout=timeout)
    if r.returncode != 0 or not os.path.exists(out):
        tail = (r.stdout + r.stderr).strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"assimp failed: {tail[0][:200]}")


def blender(src, out, timeout=600):
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
        f.write(BLENDER_SCRIPT)
        script = f.name
    try:
        code = f"import sys; sys.argv=['x','{src}','{out}']; exec(open('{script}').read())"
        r = subprocess.run(["python3", "-c", code], capture_output=True, text=True, timeout=timeout)
    finally:
        os.unlink(script)
    if r.returncode != 0 or not os.path.exists(out):
        tail = (r.stdout + r.stderr).strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"blender failed: {tail[0][:200]}")


def to_glb(src, out, read_rel=None):
    """Convert src (a file on disk) to GLB at out. read_rel(relpath) reads files referenced
    by a .gltf (relative to it). Returns the tool used."""
    ext = os.path.splitext(src)[1].lower()
    tool = tool_for(ext)
    if tool == "copy":
        shutil.copyfile(src, out)
    elif tool == "repack":
        import json
        doc = json.loads(open(src, "rb").read().decode("utf-8-sig"))
        base = os.path.dirname(src)
        rd = read_rel or (lambda u: open(os.path.join(base, u), "rb").read())
        d, b = glb.pack_gltf(doc, rd)
        open(out, "wb").write(glb.write_glb(d, b))
    elif tool == "assimp":
        if ext == ".b3d":
            from . import b3dfix
            data, changes = b3dfix.fix(open(src, "rb").read())
            if changes:
                src = src[:-4] + "_fixed.b3d"
                open(src, "wb").write(data)
        assimp(src, out)
    elif tool == "blender":
        blender(src, out)
    else:
        raise RuntimeError(f"no converter for {ext}")
    return tool
