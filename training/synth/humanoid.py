"""Humanoids (Mixamo and other conventions) and humanoid creatures.

Proportions are drawn per character between realistic (head ≈ 1/7.5 of height) and
chibi (head ≈ 1/3), arms from T-pose to A-pose, then every joint is nudged a little so
no two rest poses are identical. The body is mirrored left/right before the nudge."""

from __future__ import annotations

import numpy as np

from .naming import HumanoidNames, Namer
from .rig import X, Y, Z, Rig, add_chain, chain_points, lerp, mirror, perp, rot, unit, v3

SIDES = (("L", 1.0), ("R", -1.0))


def proportions(rng: np.random.Generator, creature: bool = False) -> dict:
    H = rng.uniform(1.2, 2.0)
    c = rng.beta(0.8, 3.0) if rng.random() < 0.8 else rng.uniform(0.5, 1.0)  # chibi-ness
    P = {
        "H": H,
        "c": c,
        "head_h": H * lerp(0.125, 0.33, c) * rng.uniform(0.9, 1.12),
        "neck_len": H * lerp(0.035, 0.012, c) * rng.uniform(0.7, 1.4),
        "leg_len": H * lerp(0.47, 0.3, c) * rng.uniform(0.92, 1.08),
        "chest_w": H * rng.uniform(0.085, 0.125) * lerp(1.0, 0.85, c),
        "waist_w": 0.0,
        "hip_w": H * rng.uniform(0.045, 0.075) * lerp(1.0, 1.15, c),
        "arm_len": H * lerp(0.36, 0.26, c) * rng.uniform(0.9, 1.12),
        "a_pose": rng.uniform(0, 50) if rng.random() < 0.85 else rng.uniform(0, 8),
        "arm_fwd": rng.uniform(-4, 12),
        "elbow_bend": rng.uniform(0, 18),
        "leg_spread": rng.uniform(0, 7),
        "thick": rng.uniform(0.8, 1.35),
        "hunch": 0.0,
        "digitigrade": False,
        "spine_n": 3,
    }
    P["waist_w"] = P["chest_w"] * rng.uniform(0.7, 1.0)
    if creature:
        P["hunch"] = rng.uniform(0.0, 0.5) if rng.random() < 0.6 else 0.0
        P["arm_len"] *= rng.uniform(1.0, 1.5)
        P["digitigrade"] = rng.random() < 0.35
        P["thick"] *= rng.uniform(0.8, 1.5)
    return P


def joints(P: dict, rng: np.random.Generator) -> dict:
    """World positions of the body joints keyed by role; sided keys end in _L/_R."""
    H = P["H"]
    hips_y = P["leg_len"] + 0.03 * H
    torso = H - hips_y - P["neck_len"] - P["head_h"]
    if torso < 0.14 * H:
        P["head_h"] -= 0.14 * H - torso
        torso = 0.14 * H
    P["torso"] = torso
    hunch = P["hunch"]

    def spine_pt(f):
        # A hunched creature leans its upper spine forward (+Z) and brings it down.
        return v3(0, hips_y + torso * f * (1 - 0.25 * hunch * f), hunch * torso * f * f * 0.9)

    J = {"hips": v3(0, hips_y, 0)}
    ns = P["spine_n"]
    fr = np.linspace(rng.uniform(0.08, 0.16), rng.uniform(0.55, 0.75), ns)
    for k in range(ns):
        J[f"spine{k}"] = spine_pt(fr[k])
    J["neck"] = spine_pt(1.0)
    head_dir = unit(v3(0, 1, hunch * 0.8))
    J["head"] = J["neck"] + head_dir * P["neck_len"]
    J["headtop"] = J["head"] + v3(0, P["head_h"], hunch * 0.1 * P["head_h"])
    top = J[f"spine{ns - 1}"]
    sh_y = J["neck"][1] - torso * rng.uniform(0.06, 0.14)
    arm_y = J["neck"][1] - torso * rng.uniform(0.1, 0.18)
    a = np.radians(P["a_pose"])
    fwd = np.radians(P["arm_fwd"])
    d1 = unit(v3(np.cos(a) * np.cos(fwd), -np.sin(a), np.cos(a) * np.sin(fwd)))
    d2 = unit(d1 + v3(0, 0, np.tan(np.radians(P["elbow_bend"]))))
    upper = P["arm_len"] * rng.uniform(0.47, 0.55)
    fore = P["arm_len"] - upper
    hand_len = P["arm_len"] * rng.uniform(0.2, 0.28)
    P["hand_len"] = hand_len
    hip_w = P["hip_w"]
    ankle_y = H * rng.uniform(0.035, 0.06)
    foot_len = H * rng.uniform(0.13, 0.16) * (1 + 0.4 * P["c"])
    spread = np.tan(np.radians(P["leg_spread"]))
    knee_f = rng.uniform(0.46, 0.54)
    for s, sx in SIDES:
        sh = v3(P["chest_w"] * rng.uniform(0.12, 0.3), sh_y, top[2] + torso * 0.02)
        arm = v3(P["chest_w"] * rng.uniform(0.85, 1.1), arm_y, top[2])
        elbow = arm + d1 * upper
        wrist = elbow + d2 * fore
        hand_end = wrist + d2 * hand_len
        up_leg = v3(hip_w, P["leg_len"], 0.0)
        if P["digitigrade"]:
            knee = v3(hip_w + spread * 0.4 * P["leg_len"], P["leg_len"] * 0.62, H * 0.06)
            ankle = v3(hip_w + spread * 0.8 * P["leg_len"], P["leg_len"] * 0.22, -H * 0.06)
            toe = v3(ankle[0], ankle_y * 0.3, H * 0.04)
        else:
            knee = v3(hip_w + spread * (P["leg_len"] - ankle_y) * (1 - knee_f), ankle_y + (P["leg_len"] - ankle_y) * knee_f, H * rng.uniform(0.0, 0.015))
            ankle = v3(hip_w + spread * (P["leg_len"] - ankle_y), ankle_y, -H * rng.uniform(0.0, 0.01))
            toe = v3(ankle[0], ankle_y * rng.uniform(0.2, 0.35), ankle[2] + foot_len * rng.uniform(0.5, 0.6))
        toe_end = v3(toe[0], toe[1], toe[2] + foot_len * rng.uniform(0.25, 0.4))
        pts = {"shoulder": sh, "arm": arm, "forearm": elbow, "hand": wrist, "hand_end": hand_end,
               "upleg": up_leg, "leg": knee, "foot": ankle, "toe": toe, "toeend": toe_end}
        for k, p in pts.items():
            J[f"{k}_{s}"] = p if sx > 0 else mirror(p)
    J["foot_len"] = foot_len
    J["ankle_y"] = ankle_y
    J["d2_L"] = d2
    J["d2_R"] = mirror(d2)
    return J


def finger_points(J, side: str, hand_len: float, n_seg: int, rng, fingers: list[int], curl: float):
    """Per finger index: the n_seg+1 points of its chain."""
    sx = 1.0 if side == "L" else -1.0
    wrist = J[f"hand_{side}"]
    along = J[f"d2_{side}"]
    across = perp(Z, along)  # toward the thumb (forward) in T-pose, palms down
    down = unit(np.cross(along, across)) * sx  # palm side
    gap = hand_len * rng.uniform(0.16, 0.22)
    out = {}
    lens = {0: 0.5, 1: 0.55, 2: 0.6, 3: 0.55, 4: 0.45}
    for f in fingers:
        L = hand_len * lens[f] * rng.uniform(0.9, 1.1)
        if f == 0:
            base = wrist + along * hand_len * 0.12 + across * gap * 1.1 + down * gap * 0.4
            d = unit(along * 0.55 + across * 0.75 + down * 0.25)
        else:
            base = wrist + along * hand_len * rng.uniform(0.42, 0.5) + across * gap * (2.5 - f)
            d = unit(along + across * (2.5 - f) * 0.06)
        axis = np.cross(d, down)
        out[f] = chain_points(base, d, L, n_seg, bend_axis=axis if np.any(axis) else None, bend_deg=curl, taper=0.75)
    P0 = {"gap": gap, "across": across, "down": down}
    return out, P0


def _perturb(rig: Rig, rng, sigma: float, start: int = 1):
    """Nudges joints (and the shapes hanging off them) so no two rest poses are identical."""
    moved = {}
    for i in range(start, len(rig)):
        d = rng.normal(0, sigma, 3)
        moved[i] = d
        rig.heads[i] = rig.heads[i] + d
        if rig.tails[i] is not None:
            rig.tails[i] = rig.tails[i] + d
    for p in rig.parts:
        d = moved.get(p.bone)
        if d is None:
            continue
        p.a = p.a + d
        p.b = p.b + d
        if p.grid is not None:
            p.grid = p.grid + d


def build_body(rig: Rig, rng: np.random.Generator, P: dict, names: HumanoidNames, opts: dict) -> dict:
    """Adds the body bones (and their shapes when `opts['shapes']`); returns bone indices by role."""
    J = joints(P, rng)
    H = P["H"]
    B = {}
    nm = names.get
    parent = -1
    if opts.get("root_bone"):
        B["root"] = rig.bone(nm("root"), -1, v3(0, 0, 0), v3(0, P["leg_len"] * 0.3, 0))
        parent = B["root"]
    ns = P["spine_n"]
    B["hips"] = rig.bone(nm("hips"), parent, J["hips"], J["spine0"] if ns else J["neck"])
    prev = B["hips"]
    for k in range(ns):
        nxt = J[f"spine{k + 1}"] if k + 1 < ns else J["neck"]
        B[f"spine{k}"] = rig.bone(nm("spine", idx=k), prev, J[f"spine{k}"], nxt)
        prev = B[f"spine{k}"]
    chest = prev
    if opts.get("neck", True):
        B["neck"] = rig.bone(nm("neck"), chest, J["neck"], J["head"])
        head_parent = B["neck"]
    else:
        head_parent = chest
    B["head"] = rig.bone(nm("head"), head_parent, J["head"], J["headtop"])
    if opts.get("headtop"):
        B["headtop"] = rig.bone(nm("headtop"), B["head"], J["headtop"], J["headtop"] + Y * P["head_h"] * 0.2, deform=False)
    for s, _ in SIDES:
        if opts.get("shoulders", True):
            B[f"shoulder_{s}"] = rig.bone(nm("shoulder", s), chest, J[f"shoulder_{s}"], J[f"arm_{s}"])
            arm_parent = B[f"shoulder_{s}"]
        else:
            arm_parent = chest
        B[f"arm_{s}"] = rig.bone(nm("arm", s), arm_parent, J[f"arm_{s}"], J[f"forearm_{s}"])
        B[f"forearm_{s}"] = rig.bone(nm("forearm", s), B[f"arm_{s}"], J[f"forearm_{s}"], J[f"hand_{s}"])
        B[f"hand_{s}"] = rig.bone(nm("hand", s), B[f"forearm_{s}"], J[f"hand_{s}"], J[f"hand_end_{s}"])
    for s, _ in SIDES:
        B[f"upleg_{s}"] = rig.bone(nm("upleg", s), B["hips"], J[f"upleg_{s}"], J[f"leg_{s}"])
        B[f"leg_{s}"] = rig.bone(nm("leg", s), B[f"upleg_{s}"], J[f"leg_{s}"], J[f"foot_{s}"])
        B[f"foot_{s}"] = rig.bone(nm("foot", s), B[f"leg_{s}"], J[f"foot_{s}"], J[f"toe_{s}"])
        if opts.get("toes", True):
            B[f"toe_{s}"] = rig.bone(nm("toe", s), B[f"foot_{s}"], J[f"toe_{s}"], J[f"toeend_{s}"])
            if opts.get("toe_end"):
                B[f"toeend_{s}"] = rig.bone(nm("toeend", s), B[f"toe_{s}"], J[f"toeend_{s}"], J[f"toeend_{s}"] + Z * 0.02 * H, deform=False)
    # Fingers
    fingers = opts.get("fingers") or []
    n_seg = opts.get("finger_segments", 3)
    fpts = {}
    for s, _ in SIDES:
        if not fingers:
            continue
        pts, info = finger_points(J, s, P["hand_len"], n_seg, rng, fingers, rng.uniform(5, 35))
        fpts[s] = (pts, info)
        for f in fingers:
            p = B[f"hand_{s}"]
            for k in range(n_seg):
                b = rig.bone(nm("finger", s, idx=k, finger=f), p, pts[f][k], pts[f][k + 1])
                B[f"finger_{s}_{f}_{k}"] = b
                p = b
            if opts.get("finger_end"):
                B[f"finger_{s}_{f}_end"] = rig.bone(nm("finger", s, idx=n_seg, finger=f), p, pts[f][n_seg],
                                                    pts[f][n_seg] + (pts[f][n_seg] - pts[f][n_seg - 1]) * 0.5, deform=False)
    J["fingers"] = fpts
    J["B"] = B
    return J


def body_shapes(rig: Rig, rng, P: dict, J: dict, style: str, fingers: list[int], n_seg: int):
    B = J["B"]
    H = P["H"]
    t = P["thick"]
    box = style == "boxy"

    def kind(default):
        return "box" if box else default

    ns = P["spine_n"]
    # Pelvis and torso
    hips = rig.heads[B["hips"]]
    pelvis_h = P["torso"] * rng.uniform(0.22, 0.32)
    rig.part(B["hips"], kind("ellipsoid"), hips - Y * pelvis_h * 0.55, hips + Y * pelvis_h * 0.5,
             P["hip_w"] * 1.9 * t, flat=rng.uniform(0.6, 0.85), side=X)
    torso_blob = rng.random() < 0.35 and ns >= 2 and not box
    spine_ids = [B[f"spine{k}"] for k in range(ns)]
    top = rig.heads[B["neck"]] if "neck" in B else rig.heads[B["head"]]
    if torso_blob:
        mid = spine_ids[len(spine_ids) // 2]
        cands = [B["hips"]] + spine_ids + [B[k] for k in ("neck", "shoulder_L", "shoulder_R", "arm_L", "arm_R") if k in B]
        rig.part(mid, "ellipsoid", hips - Y * pelvis_h * 0.2, top + Y * P["torso"] * 0.05, P["chest_w"] * 1.05 * t,
                 P["chest_w"] * 1.1 * t, flat=rng.uniform(0.55, 0.8), side=X, cands=cands)
    else:
        torso_kind = str(rng.choice(["capsule", "ellipsoid", "cyl"]))
        torso_flat = rng.uniform(0.55, 0.8)
        for k, b in enumerate(spine_ids):
            a = rig.heads[b]
            e = rig.heads[spine_ids[k + 1]] if k + 1 < ns else top
            f0, f1 = k / ns, (k + 1) / ns
            r0 = lerp(P["waist_w"], P["chest_w"], f0) * t
            r1 = lerp(P["waist_w"], P["chest_w"], f1) * t
            if k == ns - 1:
                r1 *= rng.uniform(0.7, 0.95)
            sk = kind(torso_kind)
            if sk == "ellipsoid":
                # Ellipsoids pinch to points at their ends; overlap neighbours so the torso
                # reads as one body rather than a stack of lenses.
                d = e - a
                a, e = a - d * 0.45, e + d * 0.45
                r0 = r1 = max(r0, r1)
            rig.part(b, sk, a, e, r0, r1, flat=torso_flat, side=X)
    neck_r = H * rng.uniform(0.022, 0.04) * t
    if "neck" in B:
        rig.part(B["neck"], kind("cyl"), rig.heads[B["neck"]] - Y * neck_r * 0.5, rig.heads[B["head"]] + Y * neck_r * 0.5, neck_r)
    head = rig.heads[B["head"]]
    hh = P["head_h"]
    hw = hh * rng.uniform(0.36, 0.48)
    hk = "box" if box else str(rng.choice(["ellipsoid", "ellipsoid", "capsule"]))
    if hk == "capsule":
        rig.part(B["head"], "capsule", head + Y * hw * 0.9, head + Y * (hh - hw * 0.9), hw, flat=rng.uniform(1.0, 1.15), side=X)
    else:
        rig.part(B["head"], hk, head - Y * hh * 0.02, head + Y * hh, hw, flat=rng.uniform(1.0, 1.2), side=X)
    if rng.random() < 0.4 and not box:  # nose/muzzle: a small separate part, as many low-poly heads have
        c = head + Y * hh * 0.4 + Z * hw * rng.uniform(0.8, 1.0)
        rig.part(B["head"], "cone", c, c + Z * hw * rng.uniform(0.2, 0.5), hw * rng.uniform(0.12, 0.25))
    # Arms
    arm_r = H * rng.uniform(0.026, 0.042) * t
    leg_r = H * rng.uniform(0.048, 0.075) * t
    for s, _ in SIDES:
        if f"shoulder_{s}" in B and rng.random() < 0.6:
            rig.part(B[f"shoulder_{s}"], kind("capsule"), rig.heads[B[f"shoulder_{s}"]], rig.heads[B[f"arm_{s}"]], arm_r * 0.9)
        a, e, w = rig.heads[B[f"arm_{s}"]], rig.heads[B[f"forearm_{s}"]], rig.heads[B[f"hand_{s}"]]
        rig.part(B[f"arm_{s}"], kind("capsule"), a, e, arm_r, arm_r * 0.85)
        rig.part(B[f"forearm_{s}"], kind("capsule"), e, w, arm_r * 0.8, arm_r * 0.6)
        d2 = J[f"d2_{s}"]
        hl = P["hand_len"]
        across = perp(Z, d2)
        if fingers:
            pts, info = J["fingers"][s]
            palm_end = w + d2 * hl * 0.45
            rig.part(B[f"hand_{s}"], "box" if box or rng.random() < 0.5 else "ellipsoid", w, palm_end,
                     info["gap"] * 2.3, flat=rng.uniform(0.3, 0.45), side=across)
            fr = info["gap"] * rng.uniform(0.32, 0.45)
            for f in fingers:
                for k in range(n_seg):
                    b = B[f"finger_{s}_{f}_{k}"]
                    rig.part(b, kind("capsule"), pts[f][k], pts[f][k + 1], fr * (1 - 0.12 * k), fr * (1 - 0.12 * (k + 1)))
        else:
            rig.part(B[f"hand_{s}"], "box" if box else str(rng.choice(["ellipsoid", "capsule"])), w, w + d2 * hl,
                     hl * rng.uniform(0.25, 0.35), hl * rng.uniform(0.2, 0.3), flat=rng.uniform(0.45, 0.7), side=across)
        # Legs
        u, k_, f_ = rig.heads[B[f"upleg_{s}"]], rig.heads[B[f"leg_{s}"]], rig.heads[B[f"foot_{s}"]]
        rig.part(B[f"upleg_{s}"], kind("capsule"), u, k_, leg_r, leg_r * 0.72)
        rig.part(B[f"leg_{s}"], kind("capsule"), k_, f_, leg_r * 0.68, leg_r * 0.45)
        fl = J["foot_len"]
        ay = J["ankle_y"]
        toe = J[f"toe_{s}"]
        heel = v3(f_[0], ay * 0.5, f_[2] - fl * 0.18)
        fw = H * rng.uniform(0.028, 0.04) * t
        if P["digitigrade"]:
            rig.part(B[f"foot_{s}"], kind("capsule"), f_, toe, leg_r * 0.4, leg_r * 0.35)
        else:
            rig.part(B[f"foot_{s}"], "box" if box or rng.random() < 0.5 else "ellipsoid", heel, v3(toe[0], ay * 0.5, toe[2]),
                     fw, fw * 0.95, flat=ay * 0.6 / fw + 0.2, side=X)
        if f"toe_{s}" in B:
            te = J[f"toeend_{s}"]
            rig.part(B[f"toe_{s}"], kind("ellipsoid"), v3(toe[0], toe[1], toe[2] - fl * 0.05), te, fw * 0.9, fw * 0.8, flat=0.6, side=X)


def add_hair(rig: Rig, rng, head: int, P: dict, namer: Namer, mat: int = 1):
    hh = P["head_h"]
    hw = hh * 0.42
    c = rig.heads[head] + Y * hh * 0.55
    n_chains = int(rng.integers(1, 7))
    n_seg = int(rng.integers(2, 5))
    if not rig.room(n_chains * n_seg):
        return
    ponytail = n_chains == 1
    for ci in range(n_chains):
        if ponytail:
            start = c + Y * hh * 0.3 - Z * hw * 0.9
            d = unit(v3(0, -0.6, -1))
        else:
            ang = np.radians(lerp(-70, 70, ci / max(1, n_chains - 1))) if n_chains > 1 else 0.0
            start = c + hw * 0.9 * v3(np.sin(ang), 0.3, -np.cos(ang))
            d = unit(v3(np.sin(ang) * 0.3, -1.0, -0.5))
        L = hh * rng.uniform(0.6, 2.2)
        pts = chain_points(start, d, L, n_seg, bend_axis=X, bend_deg=rng.uniform(-30, 10), rng=rng, jitter_deg=4)
        names = [namer("hair", None, ci * 10 + k + 1) for k in range(n_seg)]
        r = hw * rng.uniform(0.15, 0.35)
        add_chain(rig, head, pts, names, radii=list(np.linspace(r, r * 0.3, n_seg + 1)), kind="capsule", mat=mat, group="cloth")
    rig.part(head, "ellipsoid", rig.heads[head] + Y * hh * 0.35 - Z * hw * 0.05, rig.heads[head] + Y * hh * 1.06,
             hw * 1.08, flat=1.1, side=X, mat=mat, group="cloth")


def add_tail(rig: Rig, rng, parent: int, start, length: float, radius: float, namer: Namer, n=None, up: float = 0.0, mat=0):
    n = int(n or rng.integers(2, 9))
    if not rig.room(n):
        n = max(0, 80 - len(rig))
        if n < 1:
            return []
    d = unit(v3(0, -0.4 + up, -1))
    pts = chain_points(start, d, length, n, bend_axis=X, bend_deg=rng.uniform(-60, 40) - up * 60, rng=rng, jitter_deg=3, taper=rng.uniform(0.8, 1.0))
    names = [namer("tail", None, k + 1) for k in range(n)]
    return add_chain(rig, parent, pts, names, radii=list(np.linspace(radius, radius * rng.uniform(0.1, 0.4), n + 1)),
                     kind=str(rng.choice(["capsule", "cyl"])), mat=mat)


def add_cape(rig: Rig, rng, parent: int, P: dict, namer: Namer):
    cols = int(rng.integers(2, 5))
    rows = int(rng.integers(2, 5))
    if not rig.room(cols * rows):
        return
    base = rig.heads[parent]
    H = P["H"]
    w = P["chest_w"] * 1.1
    back = -P["chest_w"] * 0.75
    length = (base[1] - H * rng.uniform(0.1, 0.4))
    grid = np.zeros((rows + 1, cols, 3))
    ids = []
    for ci in range(cols):
        x = lerp(-w, w, ci / (cols - 1))
        col = []
        pts = [v3(x, base[1], base[2] + back)]
        for r in range(rows):
            f = (r + 1) / rows
            pts.append(v3(x * (1 + 0.5 * f), base[1] - length * f, base[2] + back - H * 0.06 * f))
        col = add_chain(rig, parent, pts, [namer("cape", None, ci * 10 + r + 1) for r in range(rows)])
        ids.extend(col)
        grid[:, ci] = np.array(pts)
    rig.sheet(ids[0], grid, thick=H * 0.006, cands=ids + [parent], mat=3, group="cloth")


def add_accessories(rig: Rig, rng, B: dict, P: dict):
    H = P["H"]
    hh = P["head_h"]
    hw = hh * 0.42
    as_node = rng.random() < 0.5
    if "head" in B and rng.random() < 0.45:
        h = rig.heads[B["head"]]
        kind = rng.choice(["cone", "tophat", "helmet"])
        if kind == "cone":
            rig.part(B["head"], "cone", h + Y * hh * 0.8, h + Y * hh * rng.uniform(1.6, 2.4), hw * 1.2, rigid=True, mat=2, group="acc", node=as_node)
        elif kind == "tophat":
            rig.part(B["head"], "cyl", h + Y * hh * 0.85, h + Y * hh * 0.9, hw * 1.7, rigid=True, mat=2, group="acc", node=as_node)
            rig.part(B["head"], "cyl", h + Y * hh * 0.88, h + Y * hh * 1.5, hw * 0.9, rigid=True, mat=2, group="acc", node=as_node)
        else:
            rig.part(B["head"], "ellipsoid", h + Y * hh * 0.3, h + Y * hh * 1.15, hw * 1.15, flat=1.1, side=X, rigid=True, mat=2, group="acc", node=as_node)
    if "hand_R" in B and rng.random() < 0.35:
        w = rig.heads[B["hand_R"]]
        grip = w + unit(rig.tails[B["hand_R"]] - w) * P["hand_len"] * 0.5
        if rng.random() < 0.5:  # sword pointing forward
            rig.part(B["hand_R"], "box", grip - Z * H * 0.05, grip + Z * H * 0.03, H * 0.012, rigid=True, mat=3, group="acc", node=as_node, side=X)
            rig.part(B["hand_R"], "box", grip + Z * H * 0.03, grip + Z * H * rng.uniform(0.3, 0.6), H * 0.02, H * 0.008, flat=0.2, side=Y, rigid=True, mat=3, group="acc", node=as_node)
        else:  # staff
            rig.part(B["hand_R"], "cyl", grip - Y * H * 0.5, grip + Y * H * 0.6, H * 0.012, rigid=True, mat=3, group="acc", node=as_node)
    if "forearm_L" in B and rng.random() < 0.2:
        f = rig.heads[B["forearm_L"]]
        t = rig.heads[B["hand_L"]]
        c = (f + t) / 2
        rig.part(B["forearm_L"], "cyl", c + X * H * 0.03, c + X * H * 0.05, H * 0.12, rigid=True, mat=2, group="acc", node=as_node)
    spine_top = max((v for k, v in B.items() if k.startswith("spine")), default=None)
    if spine_top is not None and rng.random() < 0.2:
        c = rig.heads[spine_top]
        rig.part(spine_top, "box", c - Y * H * 0.12 - Z * P["chest_w"] * 0.9, c + Y * H * 0.05 - Z * P["chest_w"] * 0.9,
                 P["chest_w"] * 0.7, flat=0.5, side=X, rigid=True, mat=2, group="acc", node=as_node)


def add_clothes(rig: Rig, rng, B: dict, P: dict):
    H = P["H"]
    t = P["thick"]
    hips = rig.heads[B["hips"]]
    if rng.random() < 0.2:  # skirt
        cands = [B["hips"], B["upleg_L"], B["upleg_R"]]
        rig.part(B["hips"], "cyl", hips + Y * H * 0.03, hips - Y * P["leg_len"] * rng.uniform(0.25, 0.6),
                 P["hip_w"] * 1.9 * t, P["hip_w"] * rng.uniform(2.3, 3.4) * t, flat=0.8, side=X, mat=1, group="cloth", cands=cands)
    if rng.random() < 0.3:  # belt
        rig.part(B["hips"], "cyl", hips + Y * H * 0.01, hips + Y * H * 0.04, P["hip_w"] * 2.0 * t, flat=0.8, side=X, mat=3, group="cloth")
    if rng.random() < 0.3:  # boots
        for s in "LR":
            k, f = rig.heads[B[f"leg_{s}"]], rig.heads[B[f"foot_{s}"]]
            rig.part(B[f"leg_{s}"], "cyl", lerp(k, f, 0.4), f - Y * 0.01 * H, H * 0.045 * t, H * 0.04 * t, mat=1, group="cloth")


def humanoid(rng: np.random.Generator) -> Rig:
    rig = Rig("humanoid")
    P = proportions(rng)
    style = str(rng.choice(["mixamo", "blender", "dotted", "underscore", "unreal", "biped", "vroid", "camel", "generic", "maya"],
                           p=[0.62, 0.05, 0.05, 0.06, 0.05, 0.04, 0.04, 0.04, 0.03, 0.02]))
    names = HumanoidNames(style, "mixamorig:" if rng.random() < 0.9 else "")
    opts: dict = {}
    if style == "mixamo":
        P["spine_n"] = 3
        opts["headtop"] = rng.random() < 0.45
        opts["toe_end"] = rng.random() < 0.45
    else:
        P["spine_n"] = int(rng.choice([1, 2, 3, 3, 4]))
        opts["headtop"] = rng.random() < 0.3
        opts["toe_end"] = rng.random() < 0.2
        opts["shoulders"] = rng.random() < 0.85
        opts["neck"] = rng.random() < 0.9
        opts["toes"] = rng.random() < 0.75
        opts["root_bone"] = style in ("biped",) or rng.random() < 0.15
    if rng.random() < 0.5:
        if rng.random() < 0.7:
            fingers = [0, 1, 2, 3, 4]
        else:
            fingers = sorted(rng.choice(5, size=int(rng.integers(1, 5)), replace=False).tolist())
        opts["fingers"] = fingers
        opts["finger_segments"] = 3 if style == "mixamo" or rng.random() < 0.8 else 2
        opts["finger_end"] = rng.random() < 0.25
    rig.kind = f"humanoid_{style}"
    J = build_body(rig, rng, P, names, opts)
    B = J["B"]
    blocky = rng.random() < 0.08
    if blocky:
        rig.rigid = True
    body_shapes(rig, rng, P, J, "boxy" if blocky or rng.random() < 0.15 else "smooth", opts.get("fingers") or [], opts.get("finger_segments", 3))
    namer = Namer(rng)
    if rng.random() < 0.3:
        add_hair(rig, rng, B["head"], P, namer)
    if rng.random() < 0.06:
        add_tail(rig, rng, B["hips"], rig.heads[B["hips"]] - Z * P["hip_w"] * 1.2, P["H"] * rng.uniform(0.3, 0.8), P["hip_w"] * 0.5, namer)
    if rng.random() < 0.1:
        add_cape(rig, rng, B[f"spine{P['spine_n'] - 1}"], P, namer)
    add_clothes(rig, rng, B, P)
    if rng.random() < 0.35:
        add_accessories(rig, rng, B, P)
    _perturb(rig, rng, P["H"] * 0.003, start=1)
    return rig


# --- humanoid creatures ---------------------------------------------------------------


def add_wings(rig: Rig, rng, parent: int, P: dict, namer: Namer, span: float, membrane: bool = True, mat: int = 1):
    n_fingers = int(rng.integers(2, 5)) if membrane else 0
    need = 2 * (3 + n_fingers * 2)
    if not rig.room(need):
        n_fingers = 0
        if not rig.room(6):
            return
    base = rig.heads[parent]
    spread = rng.uniform(0, 1)  # 0 folded-ish, 1 spread
    for s, sx in SIDES:
        root = base + v3(sx * P["chest_w"] * 0.4, P["torso"] * 0.1, -P["chest_w"] * 0.6)
        d = unit(v3(sx * lerp(0.3, 1.0, spread), lerp(0.9, 0.3, spread), -0.4))
        pts = chain_points(root, d, span * 0.55, 3, bend_axis=v3(0, 0, sx), bend_deg=-sx * lerp(60, 20, spread), taper=1.1)
        arm = add_chain(rig, parent, pts, [namer("wing", s, k + 1) for k in range(3)],
                        radii=[span * 0.03, span * 0.025, span * 0.02, span * 0.012], kind="capsule", mat=mat)
        tip = pts[-1]
        wrist = pts[-2]
        if n_fingers == 0:
            # Feathered: one sheet from the arm chain back and down.
            grid = np.array([pts, [p + v3(0, -span * 0.35, -span * 0.1) for p in pts]])
            rig.sheet(arm[1], grid, span * 0.01, cands=arm, mat=mat)
            continue
        finger_tips = []
        fids = []
        for fi in range(n_fingers):
            ang = lerp(15, 75, fi / max(1, n_fingers - 1))
            fd = rot(v3(0, 0, sx), -sx * ang) @ unit(tip - wrist)
            fp = chain_points(wrist, fd, span * rng.uniform(0.35, 0.55) * (1 - 0.35 * fi / max(1, n_fingers)), 2, taper=1.0)
            ch = add_chain(rig, arm[1], fp, [namer("wing_finger", s, fi * 10 + k + 1) for k in range(2)],
                           radii=[span * 0.012, span * 0.009, span * 0.005], kind="capsule", mat=mat)
            finger_tips.append(fp)
            fids.extend(ch)
        # Membrane rows: wrist fan across the finger chains, down to the body side.
        rows = [np.array(fp) for fp in finger_tips]
        body_edge = np.array([wrist, lerp(wrist, root, 0.5) + v3(0, -span * 0.25, 0), root + v3(0, -span * 0.3, 0)])
        rows.append(body_edge)
        grid = np.array(rows)
        rig.sheet(arm[1], grid, span * 0.006, cands=arm + fids + [parent], mat=2)


def add_horns(rig: Rig, rng, head: int, P: dict, namer: Namer, mat: int = 3):
    n = int(rng.integers(1, 4))
    if not rig.room(2 * n):
        return
    hh = P["head_h"]
    hw = hh * 0.42
    L = hh * rng.uniform(0.4, 1.4)
    for s, sx in SIDES:
        start = rig.heads[head] + v3(sx * hw * 0.6, hh * 0.85, hw * 0.2)
        pts = chain_points(start, v3(sx * 0.6, 1, rng.uniform(-0.6, 0.4)), L, n, bend_axis=v3(0, 0, sx), bend_deg=-sx * rng.uniform(0, 120), taper=0.9)
        add_chain(rig, head, pts, [namer("horn", s, k + 1) for k in range(n)], radii=list(np.linspace(hw * 0.22, 0.001 * hh + hw * 0.02, n + 1)),
                  kind="cyl", mat=mat)


def add_ears(rig: Rig, rng, head: int, P: dict, namer: Namer):
    n = int(rng.integers(1, 3))
    if not rig.room(2 * n):
        return
    hh = P["head_h"]
    hw = hh * 0.42
    L = hh * rng.uniform(0.3, 1.0)
    up = rng.uniform(0.2, 1.5)
    for s, sx in SIDES:
        start = rig.heads[head] + v3(sx * hw * 0.85, hh * rng.uniform(0.5, 0.85), 0)
        pts = chain_points(start, v3(sx, up, -0.3), L, n, taper=0.9)
        add_chain(rig, head, pts, [namer("ear", s, k + 1) for k in range(n)], radii=list(np.linspace(hw * 0.25, hw * 0.05, n + 1)),
                  kind="cone" if n == 1 else "capsule", flat=0.35, side=v3(0, 1, 0))


def humanoid_creature(rng: np.random.Generator) -> Rig:
    rig = Rig("humanoid_creature")
    kind = str(rng.choice(["goblin", "orc", "lizardman", "werewolf", "demon", "catfolk", "alien", "minotaur", "harpy", "insectoid"]))
    rig.kind = kind
    P = proportions(rng, creature=True)
    if kind in ("goblin", "alien"):
        P["head_h"] *= rng.uniform(1.2, 1.6)
        P["thick"] *= 0.8 if kind == "alien" else 1.0
    if kind in ("orc", "minotaur", "werewolf"):
        P["thick"] *= rng.uniform(1.15, 1.5)
        P["chest_w"] *= 1.3
    if kind in ("werewolf", "lizardman", "demon", "harpy"):
        P["digitigrade"] = rng.random() < 0.7
    style = str(rng.choice(["blender", "dotted", "underscore", "unreal", "camel", "generic", "maya"]))
    names = HumanoidNames(style)
    P["spine_n"] = int(rng.choice([1, 2, 3, 3, 4]))
    opts = {
        "headtop": rng.random() < 0.2,
        "shoulders": rng.random() < 0.8,
        "neck": rng.random() < 0.85,
        "toes": rng.random() < 0.8,
        "root_bone": rng.random() < 0.15,
    }
    if rng.random() < 0.6:
        opts["fingers"] = sorted(rng.choice(5, size=int(rng.integers(2, 6)), replace=False).tolist())
        opts["finger_segments"] = int(rng.choice([2, 3]))
    J = build_body(rig, rng, P, names, opts)
    B = J["B"]
    rig.rigid = rng.random() < 0.05
    body_shapes(rig, rng, P, J, "boxy" if rng.random() < 0.1 else "smooth", opts.get("fingers") or [], opts.get("finger_segments", 3))
    namer = Namer(rng)
    H = P["H"]
    head = B["head"]
    hh = P["head_h"]
    wants_tail = kind in ("lizardman", "demon", "catfolk", "werewolf") or rng.random() < 0.3
    if kind in ("lizardman", "werewolf", "minotaur") or rng.random() < 0.2:
        # Snout or jaw: a bone forward from the head with its own shape.
        if rig.room(1):
            a = rig.heads[head] + Y * hh * 0.3 + Z * hh * 0.25
            e = a + Z * hh * rng.uniform(0.3, 0.6)
            j = rig.bone(namer("jaw"), head, a, e)
            rig.part(j, "cone", a, e, hh * 0.2, hh * 0.08, flat=0.6, side=X)
    if kind in ("demon", "minotaur") or rng.random() < 0.15:
        add_horns(rig, rng, head, P, namer)
    if kind in ("catfolk", "werewolf", "goblin") or rng.random() < 0.15:
        add_ears(rig, rng, head, P, namer)
    if kind in ("demon", "harpy") or rng.random() < 0.12:
        spine_top = B[f"spine{P['spine_n'] - 1}"]
        add_wings(rig, rng, spine_top, P, namer, span=H * rng.uniform(0.6, 1.2), membrane=kind != "harpy")
    if kind == "insectoid":
        # Antennae and a second pair of arms.
        for s, sx in SIDES:
            if rig.room(3):
                st = rig.heads[head] + v3(sx * hh * 0.15, hh * 0.9, hh * 0.2)
                pts = chain_points(st, v3(sx * 0.4, 1, 0.6), hh * rng.uniform(0.6, 1.4), 3, bend_axis=X, bend_deg=40)
                add_chain(rig, head, pts, [namer("antenna", s, k + 1) for k in range(3)], radii=[hh * 0.04] * 4)
        sp = B["spine0"]
        for s, sx in SIDES:
            if rig.room(3):
                st = rig.heads[sp] + v3(sx * P["chest_w"] * 0.8, 0, P["chest_w"] * 0.2)
                pts = chain_points(st, v3(sx, -0.3, 0.5), P["arm_len"] * 0.8, 3, bend_axis=Y, bend_deg=-sx * 30)
                add_chain(rig, sp, pts, [namer("arm_lower", s, k + 1) for k in range(3)], radii=[H * 0.02, H * 0.018, H * 0.015, H * 0.01])
    if wants_tail:
        add_tail(rig, rng, B["hips"], rig.heads[B["hips"]] - Z * P["hip_w"] * 1.2, H * rng.uniform(0.4, 1.1), P["hip_w"] * rng.uniform(0.5, 1.0), namer)
    if rng.random() < 0.15:
        add_hair(rig, rng, head, P, namer)
    if rng.random() < 0.3:
        add_accessories(rig, rng, B, P)
    _perturb(rig, rng, H * 0.004, start=1)
    return rig
