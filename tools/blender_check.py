#!/usr/bin/env python3
"""Imports rigserve GLBs into headless Blender, poses one bone, and reports the deformed mesh.

This is the independent check that an exported rig deforms in a real DCC tool the way
rigserve's own linear blend skinning says it should.

Usage:
    python3 tools/blender_check.py JOBS.json OUT.json
    python3 tools/blender_check.py IN.glb OUT.json BONE [QX QY QZ QW [PX PY PZ]]

JOBS.json is a list of jobs, all run in one Blender session (start-up costs seconds):
    [{"file": "a.glb", "bone": "Spine", "rotation": [qx, qy, qz, qw],
      "pivot": [x, y, z]}, ...]
`rotation` is a unit quaternion and `pivot` the point it turns about (normally the bone's
head), both in the glTF world frame (Y up); without a pivot, the bone's head as
Blender shows it is used. The bone and everything parented to it turn rigidly by that world-space
rotation; the rest stays at rest.

A file's own animation is switched off for a bone job (pose bones back to identity, the
bind pose). A job with `"time": SECONDS` instead of a bone plays the file's first animation clip to
that time instead (glTF seconds, converted to frames at the scene's rate from the
action's first frame); `rest` is then the mesh with its armature modifiers turned off.

OUT.json is a list with one result per job, every position in the glTF world frame:
    {"file", "bone", "armatures", "joints", "vertex_groups", "skinned_objects", "actions",
     "bone_heads": {name: [x, y, z]}, "rest": [[x, y, z], ...], "posed": [[x, y, z], ...]}
`rest[i]` and `posed[i]` are the same Blender vertex before and after posing, over the
face vertices of every mesh object in the scene (the importer's bone display shape
excluded). Blender's importer may split or merge vertices, so compare by
matching rest positions, not indices.

Exits non-zero (with the reason on stderr) when a file has no armature, no skinned mesh,
a skinned mesh without vertex groups, or no bone of the given name.
"""

import json
import sys

import bpy
from mathutils import Matrix, Quaternion, Vector

# Blender's glTF importer maps glTF (x, y, z) to Blender (x, -z, y).
TO_BLENDER = Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))
TO_GLTF = TO_BLENDER.inverted()


class CheckError(Exception):
    pass


def world_vertices(objects):
    """World positions (glTF frame) of the face vertices of the evaluated (deformed) meshes.

    Loose vertices (glTF points and lines primitives) are left out: rigserve neither
    merges nor skins those.
    """
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = []
    for obj in objects:
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        to_gltf = TO_GLTF @ evaluated.matrix_world
        used = sorted({i for poly in mesh.polygons for i in poly.vertices})
        out.extend(list(to_gltf @ mesh.vertices[i].co) for i in used)
        evaluated.to_mesh_clear()
    return out


def run_job(job):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=job["file"])
    objects = list(bpy.context.scene.objects)
    armatures = [o for o in objects if o.type == "ARMATURE"]
    # The importer adds a bone display shape (an icosphere) that is not part of the file.
    shapes = {pb.custom_shape for a in armatures for pb in a.pose.bones if pb.custom_shape}
    meshes = [o for o in objects if o.type == "MESH" and o not in shapes]
    if not armatures:
        raise CheckError("no armature was imported")
    skinned = [m for m in meshes if any(mod.type == "ARMATURE" and mod.object for mod in m.modifiers)]
    if not skinned:
        raise CheckError("no mesh has an armature modifier")
    for m in skinned:
        if not m.vertex_groups:
            raise CheckError(f"skinned mesh {m.name!r} has no vertex groups")

    if "time" in job:
        return run_clip_job(job, armatures, meshes, skinned)

    for a in armatures:
        if a.animation_data and a.animation_data.action:
            # The importer plays a file's clip, which would both move the "rest" vertices
            # and override the pose set below. Without it, the rest pose is the bind pose
            # the importer reads from the inverse bind matrices (identity pose bones);
            # callers compare rest positions, so a wrong rest cannot pass unnoticed.
            a.animation_data.action = None
            for pb in a.pose.bones:
                pb.matrix_basis = Matrix.Identity(4)
    bpy.context.view_layer.update()

    owner = [a for a in armatures if job["bone"] in a.pose.bones]
    if not owner:
        raise CheckError(f"no armature has a bone named {job['bone']!r}")
    arm = owner[0]
    # Heads in the pose the file shows, which is where the glTF joints are. Blender's own
    # rest (edit-mode) armature can differ: its importer guesses a bind pose from the
    # inverse bind matrices, which for a mesh whose stored positions are not in world
    # space is not the joints' rest place.
    bone_heads = {
        pb.name: list(TO_GLTF @ a.matrix_world @ pb.head)
        for a in armatures
        for pb in a.pose.bones
    }

    rest = world_vertices(meshes)

    w, x, y, z = job["rotation"][3], *job["rotation"][:3]
    rotation = Quaternion((w, x, y, z)).normalized().to_matrix().to_4x4()
    if "pivot" in job:
        pivot = Vector(job["pivot"])
    else:
        pivot = Vector(bone_heads[job["bone"]])
    world_gltf = Matrix.Translation(pivot) @ rotation @ Matrix.Translation(-pivot)
    world = TO_BLENDER @ world_gltf @ TO_GLTF
    # The importer chooses its own bone rolls and orientations (and, see above, maybe its
    # own rest pose), so a local rotation would mean something different per file;
    # composing the world-space motion onto the bone's current armature-space matrix
    # does not depend on any of them.
    pose_bone = arm.pose.bones[job["bone"]]
    a = arm.matrix_world
    pose_bone.matrix = a.inverted() @ world @ a @ pose_bone.matrix
    bpy.context.view_layer.update()
    posed = world_vertices(meshes)

    return {
        "file": job["file"],
        "bone": job["bone"],
        "armatures": len(armatures),
        "joints": sum(len(a.data.bones) for a in armatures),
        "vertex_groups": sum(len(m.vertex_groups) for m in skinned),
        "skinned_objects": len(skinned),
        "actions": len(bpy.data.actions),
        "bone_heads": bone_heads,
        "rest": rest,
        "posed": posed,
    }


def run_clip_job(job, armatures, meshes, skinned):
    animated = [a for a in armatures if a.animation_data and a.animation_data.action]
    if not animated:
        raise CheckError("no armature has an animation")
    action = animated[0].animation_data.action
    scene = bpy.context.scene
    fps = scene.render.fps / scene.render.fps_base
    modifiers = [mod for m in skinned for mod in m.modifiers if mod.type == "ARMATURE"]
    for mod in modifiers:
        mod.show_viewport = False
    bpy.context.view_layer.update()
    rest = world_vertices(meshes)
    for mod in modifiers:
        mod.show_viewport = True
    frame = action.frame_range[0] + job["time"] * fps
    scene.frame_set(int(frame), subframe=frame - int(frame))
    bpy.context.view_layer.update()
    posed = world_vertices(meshes)
    return {
        "file": job["file"],
        "time": job["time"],
        "frame": frame,
        "armatures": len(armatures),
        "joints": sum(len(a.data.bones) for a in armatures),
        "vertex_groups": sum(len(m.vertex_groups) for m in skinned),
        "skinned_objects": len(skinned),
        "actions": len(bpy.data.actions),
        "rest": rest,
        "posed": posed,
    }


def parse_args(argv):
    if len(argv) == 3 and argv[1].endswith(".json"):
        with open(argv[1]) as f:
            return json.load(f), argv[2]
    if len(argv) in (4, 8, 11):
        job = {"file": argv[1], "bone": argv[3], "rotation": [0.0, 0.0, 0.0, 1.0]}
        if len(argv) >= 8:
            job["rotation"] = [float(v) for v in argv[4:8]]
        if len(argv) == 11:
            job["pivot"] = [float(v) for v in argv[8:11]]
        return [job], argv[2]
    sys.exit(__doc__)


def main():
    jobs, out_path = parse_args(sys.argv)
    results = []
    for job in jobs:
        try:
            results.append(run_job(job))
        except CheckError as e:
            sys.exit(f"{job['file']}: {e}")
    with open(out_path, "w") as f:
        json.dump(results, f)


if __name__ == "__main__":
    main()
