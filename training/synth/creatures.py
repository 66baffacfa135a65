"""Non-humanoid organic categories: quadrupeds, flyers, insects/spiders, fish/snakes,
and the catch-all of blobs, plants and fruit characters."""

from __future__ import annotations

import numpy as np

from .naming import Namer
from .rig import MAX_BONES, X, Y, Z, Rig, add_chain, chain_points, lerp, perp, rot, unit, v3

SIDES = (("L", 1.0), ("R", -1.0))


def _radii(r0: float, r1: float, n: int) -> list[float]:
    return list(np.linspace(r0, r1, n + 1))


def _overlap(a, e, f: float):
    d = e - a
    return a - d * f, e + d * f


def _leg(rig: Rig, parent: int, pts, namer: Namer, base: str, lr: str | None, r0: float, r1: float, kind="capsule", end=False, **kw):
    """A chain named `base` on side `lr`, one tapered shape per bone."""
    n = len(pts) - 1
    names = [namer(base, lr, k + 1) for k in range(n)]
    return add_chain(rig, parent, pts, names, radii=_radii(r0, r1, n), kind=kind,
                     end_bone=namer(base + "_end", lr) if end else None, **kw)


# --- quadrupeds --------------------------------------------------------------------------

QUAD_PRESETS = {
    # body length range, leg/body, neck/body, neck angle, head/body, girth/body, plantigrade, tail/body, tail bones
    "cat": ((0.25, 0.5), (0.7, 0.9), (0.25, 0.35), (25, 45), (0.3, 0.4), (0.18, 0.24), False, (0.8, 1.2), (3, 8)),
    "dog": ((0.35, 1.0), (0.8, 1.1), (0.3, 0.45), (30, 50), (0.35, 0.5), (0.2, 0.28), False, (0.4, 0.8), (2, 6)),
    "horse": ((0.9, 1.4), (1.1, 1.4), (0.6, 0.8), (40, 60), (0.45, 0.6), (0.22, 0.3), False, (0.5, 0.8), (2, 5)),
    "deer": ((0.7, 1.2), (1.1, 1.4), (0.5, 0.7), (40, 65), (0.35, 0.45), (0.18, 0.24), False, (0.1, 0.2), (1, 2)),
    "cow": ((1.3, 1.9), (0.7, 0.9), (0.3, 0.45), (15, 35), (0.35, 0.45), (0.3, 0.4), False, (0.5, 0.7), (2, 5)),
    "elephant": ((1.8, 3.2), (0.8, 1.0), (0.1, 0.2), (10, 25), (0.35, 0.45), (0.35, 0.45), True, (0.3, 0.5), (2, 5)),
    "bear": ((1.0, 1.8), (0.55, 0.75), (0.2, 0.3), (10, 30), (0.3, 0.38), (0.3, 0.38), True, (0.05, 0.12), (0, 2)),
    "lizard": ((0.2, 1.6), (0.25, 0.4), (0.15, 0.3), (0, 15), (0.3, 0.45), (0.15, 0.22), True, (1.0, 1.8), (4, 8)),
    "giraffe": ((1.4, 2.0), (1.4, 1.8), (1.2, 1.6), (60, 75), (0.3, 0.4), (0.22, 0.28), False, (0.4, 0.6), (2, 4)),
    "pig": ((0.6, 1.3), (0.45, 0.6), (0.1, 0.2), (5, 20), (0.35, 0.45), (0.3, 0.38), False, (0.1, 0.2), (1, 3)),
    "rodent": ((0.08, 0.3), (0.35, 0.5), (0.15, 0.25), (15, 35), (0.35, 0.5), (0.25, 0.32), True, (0.8, 1.4), (3, 8)),
    "dragon": ((1.5, 4.0), (0.5, 0.8), (0.6, 1.0), (25, 50), (0.35, 0.5), (0.2, 0.3), False, (1.2, 2.0), (5, 8)),
}


def quadruped(rng: np.random.Generator, kind: str | None = None, category: str = "quadruped") -> Rig:
    kind = kind or str(rng.choice([k for k in QUAD_PRESETS if k != "dragon"]))
    pr = QUAD_PRESETS[kind]
    rig = Rig(category)
    rig.kind = kind
    namer = Namer(rng)
    U = rng.uniform
    S = U(*pr[0])
    leg_h = S * U(*pr[1])
    neck_len = S * U(*pr[2])
    neck_ang = np.radians(U(*pr[3]))
    head_len = S * U(*pr[4])
    girth = S * U(*pr[5])
    plant = pr[6] if rng.random() < 0.85 else not pr[6]
    tail_len = S * U(*pr[7])
    tail_n = int(rng.integers(pr[8][0], pr[8][1] + 1))
    width = girth * U(0.55, 0.8)
    pelvis = v3(0, leg_h + girth * 0.15, -S / 2)
    chest = v3(0, leg_h * U(0.95, 1.08) + girth * 0.2, S / 2)
    rig.rigid = rng.random() < 0.07

    parent = -1
    if rng.random() < 0.2:
        parent = rig.bone(namer("root"), -1, v3(0, 0, 0), v3(0, leg_h * 0.5, 0))
    n_sp = int(rng.integers(2, 6))
    arch = U(-0.05, 0.12) * S
    sp = [lerp(pelvis, chest, t) + Y * arch * np.sin(np.pi * t) for t in np.linspace(0, 1, n_sp)]
    neck_dir = unit(v3(0, np.sin(neck_ang), np.cos(neck_ang)))
    neck_base = chest + neck_dir * girth * 0.4
    names = [namer("hips")] + [namer("spine", None, k) for k in range(1, n_sp)]
    spine = add_chain(rig, parent, sp + [neck_base], names)
    hips, chest_b = spine[0], spine[-1]
    # Neck and head
    n_nk = int(rng.integers(1, 5))
    nk = chain_points(neck_base, neck_dir, neck_len, n_nk, bend_axis=X, bend_deg=U(0, 25))
    neck = add_chain(rig, chest_b, nk, [namer("neck", None, k + 1) for k in range(n_nk)], radii=_radii(girth * 0.45, girth * 0.3, n_nk))
    head_dir = unit(v3(0, -np.tan(np.radians(U(0, 50))), 1))
    hpos = nk[-1]
    htail = hpos + head_dir * head_len
    head = rig.bone(namer("head"), neck[-1], hpos, htail)
    hr = head_len * U(0.28, 0.4)
    rig.part(head, "ellipsoid", hpos - head_dir * hr * 0.5, hpos + head_dir * head_len * 0.55, hr, hr * 0.9, flat=U(0.9, 1.2), side=X)
    snout_a = hpos + head_dir * head_len * 0.4 - Y * hr * 0.2
    if rng.random() < 0.45:
        jaw = rig.bone(namer("jaw"), head, hpos - Y * hr * 0.4 + head_dir * hr * 0.3, htail - Y * hr * 0.5)
        rig.part(jaw, "cone" if kind in ("lizard", "dragon") else "ellipsoid", rig.heads[jaw], htail - Y * hr * 0.5, hr * 0.45, hr * 0.2, flat=0.5, side=X)
        rig.part(head, "ellipsoid", snout_a, htail, hr * 0.6, hr * 0.35, flat=0.7, side=X)
    else:
        rig.part(head, str(rng.choice(["ellipsoid", "cyl", "capsule"])), snout_a, htail, hr * 0.55, hr * 0.35, flat=0.8, side=X)
    if kind == "elephant" and rig.room(4):
        tr = chain_points(htail - Y * hr * 0.2, v3(0, -1, 0.3), leg_h * 0.85, int(rng.integers(2, 5)), bend_axis=X, bend_deg=-40)
        _leg(rig, head, tr, namer, "trunk", None, hr * 0.35, hr * 0.12)
    if rng.random() < 0.6 and rig.room(4):
        n_ear = int(rng.integers(1, 3))
        ear_len = hr * (U(2.0, 3.0) if kind in ("elephant", "rodent") else U(0.6, 1.6))
        for s, sx in SIDES:
            st = hpos + v3(sx * hr * 0.6, hr * 0.7, -hr * 0.1)
            pts = chain_points(st, v3(sx * 0.6, 1.0, -0.5), ear_len, n_ear, taper=0.9)
            _leg(rig, head, pts, namer, "ear", s, hr * 0.35, hr * 0.08, kind="cone" if n_ear == 1 else "capsule", flat=0.3, side=v3(0, 1, -1))
    if kind in ("cow", "deer", "dragon") and rig.room(4):
        n_h = int(rng.integers(1, 3))
        for s, sx in SIDES:
            st = hpos + v3(sx * hr * 0.4, hr * 0.8, 0)
            pts = chain_points(st, v3(sx, 1.2, -0.3), hr * U(0.8, 2.5), n_h, bend_axis=Z, bend_deg=sx * U(0, 50))
            _leg(rig, head, pts, namer, "horn", s, hr * 0.18, hr * 0.03, kind="cyl", mat=3)
    # Body shapes
    if rng.random() < 0.4:
        mid = spine[len(spine) // 2]
        rig.part(mid, "ellipsoid", pelvis - Z * girth * 0.6, chest + Z * girth * 0.5, width, width * U(0.9, 1.1),
                 flat=girth / width, side=X, cands=list(spine) + [neck[0]])
    else:
        seg_kind = str(rng.choice(["capsule", "ellipsoid"]))
        for k, b in enumerate(spine):
            a, e = rig.heads[b], rig.tails[b]
            r = width * (1.0 if 0 < k < len(spine) - 1 else 0.92)
            if k == 0:
                a = a - Z * girth * 0.4
            if seg_kind == "ellipsoid":
                # Ellipsoids taper to points at their ends; overlap them so the body is continuous.
                a, e = _overlap(a, e, 0.35)
            rig.part(b, seg_kind, a, e, r, r, flat=girth / width, side=X)
    # Legs
    leg_r = girth * (U(0.35, 0.5) if kind in ("elephant", "bear", "cow") else U(0.18, 0.3))
    foot = leg_h * U(0.08, 0.15)
    segs = int(rng.choice([3, 4]))
    toe_bone = rng.random() < 0.5
    for s, sx in SIDES:
        w = width * U(0.55, 0.8)
        # Front: [scapula] shoulder → elbow → wrist → toe
        sh = v3(sx * w, chest[1] - girth * 0.3, chest[2] - S * 0.02)
        pts = [sh, v3(sx * w, leg_h * 0.55, chest[2] - S * 0.08), v3(sx * w, leg_h * (0.04 if plant else 0.14), chest[2] - S * 0.02)]
        if segs == 4:
            pts.insert(0, v3(sx * w * 0.7, chest[1] + girth * 0.1, chest[2] - S * 0.12))
        pts.append(v3(sx * w, 0.0 if plant else leg_h * 0.03, pts[-1][2] + foot))
        if toe_bone:
            pts.append(pts[-1] + Z * foot * 0.6)
        _leg(rig, chest_b, pts, namer, "front_leg", s, leg_r, leg_r * 0.55, end=rng.random() < 0.2)
        # Hind: hip → knee → hock/ankle → toe
        hp = v3(sx * w, pelvis[1] - girth * 0.25, pelvis[2])
        if plant:
            pts = [hp, v3(sx * w, leg_h * 0.52, pelvis[2] + S * 0.1), v3(sx * w, leg_h * 0.05, pelvis[2] - S * 0.02)]
            pts.append(v3(sx * w, 0.0, pts[-1][2] + foot * 1.3))
        else:
            pts = [hp, v3(sx * w, leg_h * 0.6, pelvis[2] + S * 0.12), v3(sx * w, leg_h * 0.3, pelvis[2] - S * 0.1)]
            pts.append(v3(sx * w, leg_h * 0.04, pelvis[2] - S * 0.05))
        if segs == 4 or toe_bone:
            pts.append(pts[-1] + Z * foot)
        _leg(rig, hips, pts, namer, "back_leg", s, leg_r * 1.15, leg_r * 0.55, end=rng.random() < 0.2)
    # Tail
    if tail_n and rig.room(tail_n):
        up = U(-0.6, 0.9) if kind in ("dog", "cat", "rodent") else U(-0.8, 0.1)
        pts = chain_points(pelvis - Z * girth * 0.3 + Y * girth * 0.1, v3(0, up, -1), tail_len, tail_n,
                           bend_axis=X, bend_deg=U(-40, 40), rng=rng, jitter_deg=5, taper=U(0.85, 1.0))
        r0 = girth * (U(0.2, 0.4) if kind in ("lizard", "dragon") else U(0.08, 0.18))
        _leg(rig, hips, pts, namer, "tail", None, r0, r0 * U(0.1, 0.6))
    if rng.random() < 0.15 and rig.room(1):  # saddle / collar as a separate rigid prop
        rig.part(spine[len(spine) // 2], "box", rig.heads[spine[len(spine) // 2]] + Y * girth * 0.7 - Z * S * 0.1,
                 rig.heads[spine[len(spine) // 2]] + Y * girth * 0.7 + Z * S * 0.15, width * 0.8, flat=0.2, side=X,
                 rigid=True, mat=2, group="acc", node=rng.random() < 0.5)
    rig.extra = {"girth": girth, "width": width, "chest": chest_b, "S": S}
    return rig


# --- flyers ------------------------------------------------------------------------------


def membrane_wing(rig: Rig, rng, parent: int, root, out_dir, span: float, namer: Namer, side: str,
                  n_fingers: int, body_anchor, mat: int = 1):
    sx = 1.0 if side == "L" else -1.0
    arm_pts = chain_points(root, out_dir, span * 0.45, 2, bend_axis=Y, bend_deg=sx * rng.uniform(-40, 10))
    arm = _leg(rig, parent, arm_pts, namer, "wing", side, span * 0.035, span * 0.02, mat=mat)
    wrist = arm_pts[-1]
    fingers, fids = [], []
    base_d = unit(arm_pts[-1] - arm_pts[-2])
    for fi in range(n_fingers):
        ang = lerp(5, 120, fi / max(1, n_fingers - 1))
        fd = rot(Y, -sx * ang) @ base_d + v3(0, rng.uniform(-0.1, 0.1), 0)
        n = int(rng.integers(1, 4))
        fp = chain_points(wrist, fd, span * rng.uniform(0.35, 0.6) * (1 - 0.3 * fi / max(1, n_fingers)), n)
        fids += _leg(rig, arm[-1], fp, namer, "finger", side, span * 0.012, span * 0.004, mat=mat)
        # Resample each finger to 3 points so the membrane grid is regular.
        fingers.append([fp[0], lerp(fp[0], fp[-1], 0.5), fp[-1]])
    rows = fingers + [[wrist, lerp(wrist, body_anchor, 0.5), body_anchor]]
    rig.sheet(arm[-1], np.array(rows), span * 0.008, cands=arm + fids + [parent], mat=2)


def feather_wing(rig: Rig, rng, parent: int, root, span: float, namer: Namer, side: str, spread: bool, n_seg: int, body_len: float, mat: int = 1):
    sx = 1.0 if side == "L" else -1.0
    if spread:
        d = unit(v3(sx, rng.uniform(-0.1, 0.4), rng.uniform(-0.3, 0.1)))
        pts = chain_points(root, d, span, n_seg, bend_axis=Y, bend_deg=sx * rng.uniform(-30, 0), taper=1.1)
    else:
        # Folded: zigzag along the body side, tip pointing back.
        L = body_len
        pts = [root, root + v3(sx * L * 0.15, -L * 0.1, -L * 0.25), root + v3(sx * L * 0.2, -L * 0.05, L * 0.05)]
        while len(pts) < n_seg + 1:
            pts.append(pts[-1] + v3(sx * L * 0.02, -L * 0.03, -L * 0.45))
        pts = pts[: n_seg + 1]
    arm = _leg(rig, parent, pts, namer, "wing", side, span * 0.04, span * 0.015, mat=mat)
    chord = span * rng.uniform(0.3, 0.55) if spread else body_len * 0.3
    trail = [p + v3(0, -chord * 0.1, -chord * (1 - 0.5 * k / n_seg)) for k, p in enumerate(pts)]
    if not spread:
        trail = [p + v3(sx * 0.01 * body_len, -chord, 0) for p in pts]
    rig.sheet(arm[0], np.array([pts, trail]), span * 0.01, cands=arm + [parent], mat=mat)
    return arm


def bird_flyer(rng: np.random.Generator) -> Rig:
    kind = str(rng.choice(["bird", "bird", "bird", "bat", "dragon", "pterosaur"]))
    if kind == "dragon":
        rig = quadruped(rng, "dragon", category="bird_flyer")
        namer = Namer(rng)
        ex = rig.extra
        chest = ex["chest"]
        span = ex["S"] * rng.uniform(1.0, 1.8)
        for s, sx in SIDES:
            if not rig.room(8):
                break
            root = rig.heads[chest] + v3(sx * ex["width"] * 0.5, ex["girth"] * 0.6, -ex["S"] * 0.1)
            out = unit(v3(sx, rng.uniform(0.2, 0.9), -0.2))
            anchor = rig.heads[0] + v3(sx * ex["width"] * 0.5, ex["girth"] * 0.3, 0)
            membrane_wing(rig, rng, chest, root, out, span, namer, s, int(rng.integers(2, 5)), anchor)
        return rig
    rig = Rig("bird_flyer")
    rig.kind = kind
    namer = Namer(rng)
    U = rng.uniform
    L = U(0.08, 0.8) if kind != "pterosaur" else U(0.5, 2.0)  # body length
    r = L * U(0.22, 0.32)
    leg_h = L * U(0.3, 0.9) if kind == "bird" else L * 0.3
    tilt = np.radians(U(0, 35) if kind == "bird" else U(-10, 15))
    axis = unit(v3(0, np.sin(tilt), np.cos(tilt)))
    c = v3(0, leg_h + r, 0)
    parent = -1
    if rng.random() < 0.25:
        parent = rig.bone(namer("root"), -1, v3(0, 0, 0), c)
    n_body = int(rng.integers(1, 3))
    body_pts = [c - axis * L * 0.3 + axis * L * 0.6 * k / max(1, n_body) for k in range(n_body + 1)]
    if n_body == 1:
        body_pts = [c - axis * L * 0.1, c + axis * L * 0.4]
    body = add_chain(rig, parent, body_pts, [namer("body")] + [namer("chest")] * (n_body - 1))
    rig.part(body[0], "ellipsoid", c - axis * L * 0.5, c + axis * L * 0.5, r, r * U(0.7, 1.0), flat=U(0.9, 1.2), side=X, cands=body + [body[0]])
    chest = body[-1]
    # Neck + head + beak
    n_nk = int(rng.integers(1, 5))
    neck_len = L * (U(0.15, 0.9) if kind == "bird" else U(0.1, 0.3))
    nk = chain_points(c + axis * L * 0.4, unit(axis + Y * U(0.5, 2.0)), neck_len, n_nk, bend_axis=X, bend_deg=U(-40, 20))
    neck = add_chain(rig, chest, nk, [namer("neck", None, k + 1) for k in range(n_nk)], radii=_radii(r * 0.45, r * 0.3, n_nk))
    hr = r * U(0.45, 0.7)
    head_tip = nk[-1] + unit(v3(0, 0.3, 1)) * hr * 1.5
    head = rig.bone(namer("head"), neck[-1], nk[-1], head_tip)
    rig.part(head, "ellipsoid", nk[-1] - Y * hr * 0.6, nk[-1] + Y * hr * 1.2, hr, flat=1.1, side=X)
    if kind in ("bird", "pterosaur"):
        bl = hr * (U(0.6, 3.5) if kind == "bird" else U(3, 6))
        b0 = nk[-1] + Z * hr * 0.8 + Y * hr * 0.2
        beak = rig.bone(namer("beak"), head, b0, b0 + unit(v3(0, U(-0.6, 0.1), 1)) * bl)
        rig.part(beak, "cone", b0, rig.tails[beak], hr * U(0.2, 0.45), flat=U(0.5, 1.0), side=X, mat=3)
    else:
        for s, sx in SIDES:  # bat ears
            if rig.room(1):
                e0 = nk[-1] + v3(sx * hr * 0.5, hr * 0.8, 0)
                e = rig.bone(namer("ear", s), head, e0, e0 + v3(sx * hr * 0.5, hr * 1.5, -hr * 0.2))
                rig.part(e, "cone", e0, rig.tails[e], hr * 0.4, flat=0.3, side=Z)
    # Wings
    span = L * (U(0.8, 2.0) if kind == "bird" else U(1.5, 3.0))
    spread = rng.random() < 0.6
    n_seg = int(rng.integers(3, 5))
    for s, sx in SIDES:
        root = c + axis * L * 0.2 + v3(sx * r * 0.7, r * 0.5, 0)
        if kind == "bird":
            feather_wing(rig, rng, chest, root, span, namer, s, spread, n_seg, L)
        else:
            anchor = c - axis * L * 0.4 + v3(sx * r * 0.6, 0, 0)
            membrane_wing(rig, rng, chest, root, unit(v3(sx, U(0.0, 0.4), 0.1)), span, namer, s, int(rng.integers(3, 5)), anchor)
    # Legs: thigh (often hidden in the body), shin, tarsus, toe.
    n_leg = int(rng.integers(2, 5))
    for s, sx in SIDES:
        hip = c - axis * L * 0.1 + v3(sx * r * 0.5, -r * 0.6, 0)
        knee = v3(sx * r * 0.55, lerp(hip[1], 0, 0.45), hip[2] + L * 0.08)
        ankle = v3(sx * r * 0.55, leg_h * 0.05, hip[2] - L * 0.02)
        toe = v3(sx * r * 0.55, 0.0, ankle[2] + L * 0.12)
        toe_end = toe + Z * L * 0.08
        pts = {2: [knee, ankle, toe], 3: [hip, knee, ankle, toe], 4: [hip, knee, ankle, toe, toe_end]}[n_leg]
        leg = _leg(rig, body[0], pts, namer, "leg", s, r * 0.12, r * 0.06, mat=3)
        if rng.random() < 0.4 and rig.room(3):
            for t, ang in enumerate((-30, 0, 30)):
                d = rot(Y, ang) @ Z
                # Toes start just off the ankle: a joint on top of its parent has no direction.
                tt = rig.bone(namer("toe", s, t + 1), leg[-1], ankle + d * L * 0.03, ankle + d * L * 0.15 - Y * leg_h * 0.05)
                rig.part(tt, "capsule", rig.heads[tt], rig.tails[tt], r * 0.04, mat=3)
    # Tail feathers
    tail0 = c - axis * L * 0.45
    n_t = int(rng.choice([1, 1, 2, 3]))
    tl = L * U(0.2, 0.8)
    tail_b = []
    for k in range(n_t):
        ang = lerp(-25, 25, k / max(1, n_t - 1)) if n_t > 1 else 0.0
        d = rot(Y, ang) @ unit(-axis + Y * U(-0.3, 0.3))
        tail_b.append(rig.bone(namer("tail", None, k + 1), body[0], tail0, tail0 + d * tl))
    fan = np.array([[tail0 + v3(-r * 0.3, 0, 0), tail0 + v3(r * 0.3, 0, 0)],
                    [rig.tails[tail_b[0]] + v3(-tl * 0.4, 0, 0), rig.tails[tail_b[-1]] + v3(tl * 0.4, 0, 0)]])
    rig.sheet(tail_b[0], fan, L * 0.01, cands=tail_b + [body[0]], mat=1)
    return rig


# --- insects and spiders -------------------------------------------------------------------


def insect_spider(rng: np.random.Generator) -> Rig:
    kind = str(rng.choice(["spider", "spider", "ant", "beetle", "mantis", "scorpion", "crab", "bee", "centipede"]))
    rig = Rig("insect_spider")
    rig.kind = kind
    namer = Namer(rng)
    U = rng.uniform
    L = np.exp(U(np.log(0.03), np.log(2.5)))  # body length
    rig.rigid = rng.random() < 0.15
    clear = L * U(0.15, 0.4)
    thr = L * U(0.12, 0.2)
    c = v3(0, clear + thr, 0)
    parent = -1
    if rng.random() < 0.2:
        parent = rig.bone(namer("root"), -1, v3(0, 0, 0), c)
    thorax = rig.bone(namer("thorax" if kind != "spider" else "cephalothorax"), parent, c, c + Z * L * 0.25)
    rig.part(thorax, "ellipsoid", c - Z * L * 0.15, c + Z * L * 0.2, thr, flat=U(0.6, 0.9), side=X)
    # Abdomen segments
    n_ab = int(rng.integers(1, 4)) if kind != "centipede" else int(rng.integers(5, 9))
    ab_len = L * (U(0.35, 0.6) if kind != "centipede" else U(1.0, 2.0))
    lift = U(-0.1, 0.5) if kind in ("spider", "ant", "bee") else 0.0
    ab_pts = chain_points(c - Z * L * 0.12, v3(0, lift, -1), ab_len, n_ab)
    ab_r = thr * (U(1.1, 1.8) if kind in ("spider", "bee", "ant") else U(0.8, 1.1))
    if kind == "centipede":
        ab_r = thr
    ab = add_chain(rig, thorax, ab_pts, [namer("abdomen", None, k + 1) for k in range(n_ab)])
    for k, b in enumerate(ab):
        rr = ab_r * (1 - 0.3 * abs(k - n_ab / 2) / max(1, n_ab))
        rig.part(b, "ellipsoid", ab_pts[k] + Z * rr * 0.2, ab_pts[k + 1] - Z * rr * 0.1, rr, flat=U(0.6, 0.9), side=X)
    # Head
    head = thorax
    if kind != "spider" and kind != "crab":
        h0 = c + Z * L * 0.2
        head = rig.bone(namer("head"), thorax, h0, h0 + Z * L * 0.2)
        rig.part(head, "ellipsoid", h0, h0 + Z * L * 0.22, thr * U(0.6, 0.9), flat=0.8, side=X)
    hp = rig.heads[head] + Z * L * 0.15
    # Mandibles / chelicerae
    if rng.random() < 0.7 and rig.room(2):
        for s, sx in SIDES:
            m0 = hp + v3(sx * thr * 0.3, -thr * 0.3, 0)
            m = rig.bone(namer("mandible", s), head, m0, m0 + v3(-sx * thr * 0.2, -thr * 0.2, L * 0.12))
            rig.part(m, "cone", m0, rig.tails[m], thr * 0.18, mat=3)
    # Antennae
    if kind not in ("spider", "scorpion") and rig.room(8):
        n = int(rng.integers(2, 5))
        for s, sx in SIDES:
            pts = chain_points(hp + v3(sx * thr * 0.3, thr * 0.3, 0), v3(sx * 0.5, 0.8, 1), L * U(0.3, 1.0), n, bend_axis=v3(1, 0, 0), bend_deg=U(-20, 60))
            _leg(rig, head, pts, namer, "antenna", s, thr * 0.07, thr * 0.03)
    # Legs
    pairs = {"spider": 4, "scorpion": 4, "crab": 4}.get(kind, 3)
    if kind == "centipede":
        pairs = min(n_ab + 1, 8)
    n_seg = int(rng.integers(3, 6))
    while not rig.room(pairs * 2 * n_seg + 12) and n_seg > 2:
        n_seg -= 1
    leg_len = L * (U(1.2, 2.2) if kind in ("spider", "crab") else U(0.7, 1.3))
    for pi in range(pairs):
        if kind == "centipede":
            host = ab[min(pi, n_ab - 1)] if pi else thorax
            ang = 90.0
        else:
            host = thorax
            ang = lerp(40, 150, pi / max(1, pairs - 1))
        base_c = rig.heads[host]
        for s, sx in SIDES:
            out = v3(sx * np.sin(np.radians(ang)), 0, np.cos(np.radians(ang)))
            root = base_c + out * thr * 0.8 - Y * thr * 0.3
            knee_h = clear + thr + L * U(0.1, 0.5) if kind == "spider" else clear + thr * 0.5
            foot = v3(root[0], 0, root[2]) + out * leg_len * 0.65
            knee = lerp(root, foot, 0.35)
            knee[1] = knee_h
            pts = [root, knee, foot]
            # Resample to n_seg segments along the root→knee→foot polyline.
            seg = np.linspace(0, 2, n_seg + 1)
            pts = [lerp(pts[int(min(t, 1.999))], pts[int(min(t, 1.999)) + 1], t - int(min(t, 1.999))) for t in seg]
            _leg(rig, host, pts, namer, "leg", s + str(pi + 1), thr * 0.2, thr * 0.07, mat=0)
    if kind in ("scorpion", "crab", "mantis") and rig.room(10):
        for s, sx in SIDES:
            root = hp + v3(sx * thr * 0.6, -thr * 0.1, -L * 0.05)
            pts = chain_points(root, v3(sx * 0.7, 0.2, 1), L * U(0.5, 0.9), 3, bend_axis=Y, bend_deg=-sx * 60)
            arm = _leg(rig, head, pts, namer, "claw", s, thr * 0.18, thr * 0.15, mat=0)
            tip = pts[-1]
            d = unit(pts[-1] - pts[-2])
            for k, side_off in enumerate((0.25, -0.25)):
                p0 = tip
                p1 = tip + unit(d + v3(0, side_off, 0)) * L * 0.2
                f = rig.bone(namer("pincer", s, k + 1), arm[-1], p0, p1)
                rig.part(f, "cone", p0, p1, thr * 0.14, flat=0.6, side=Y, mat=3)
    if kind == "scorpion" and rig.room(7):
        n = int(rng.integers(4, 7))
        pts = chain_points(ab_pts[-1], v3(0, 0.6, -1), L * U(0.8, 1.3), n, bend_axis=X, bend_deg=-200)
        _leg(rig, ab[-1], pts, namer, "tail", None, thr * 0.35, thr * 0.15)
        sting = rig.bone(namer("stinger"), len(rig) - 1, pts[-1], pts[-1] + unit(pts[-1] - pts[-2]) * L * 0.15)
        rig.part(sting, "cone", rig.heads[sting], rig.tails[sting], thr * 0.15, mat=3)
    if kind in ("bee", "beetle", "mantis") and rig.room(4):
        n_w = int(rng.choice([2, 4]))
        for s, sx in SIDES:
            for k in range(n_w // 2):
                w0 = c + v3(sx * thr * 0.4, thr * 0.7, -L * 0.05 * k)
                w1 = w0 + unit(v3(sx, U(0.1, 0.6), -0.6 - 0.5 * k)) * L * U(0.6, 1.0)
                wb = rig.bone(namer("wing", s, k + 1), thorax, w0, w1)
                rig.part(wb, "ellipsoid", w0, w1, L * U(0.12, 0.22), flat=0.06, side=v3(0, 0, 1), mat=1, rigid=True)
    return rig


# --- fish, snakes and long tails ---------------------------------------------------------


def fish_snake_tail(rng: np.random.Generator) -> Rig:
    kind = str(rng.choice(["snake", "snake", "fish", "fish", "eel", "whale", "dolphin", "shark", "seahorse", "worm", "tadpole"]))
    rig = Rig("fish_snake_tail")
    rig.kind = kind
    namer = Namer(rng)
    U = rng.uniform
    if kind in ("snake", "eel", "worm"):
        n = int(rng.integers(10, 31) if kind != "worm" else rng.integers(5, 16))
        L = U(0.8, 6.0) if kind != "worm" else U(0.1, 1.0)
        r = L * U(0.012, 0.035) * (2.0 if kind == "worm" else 1.0)
        n = min(n, MAX_BONES - 6)
        # A snake lies on the ground in an S-curve; the spine runs tail → head in +Z.
        t = np.linspace(0, 1, n + 1)
        amp = L * U(0.0, 0.12)
        waves = U(0.5, 2.0)
        zs = (t - 0.5) * L * U(0.6, 0.95)
        xs = amp * np.sin(2 * np.pi * waves * t)
        ys = np.full_like(t, r) if kind != "eel" else np.full_like(t, L * 0.2)
        pts = [v3(x, y, z) for x, y, z in zip(xs, ys, zs)]
        head_first = rng.random() < 0.5
        if head_first:
            pts = pts[::-1]
        radius = r * np.where(t < 0.3, 0.25 + 2.5 * t, 1.0)
        if head_first:
            radius = radius[::-1]
        names = [namer("spine", None, k + 1) for k in range(n)]
        spine = add_chain(rig, -1, pts, names, radii=list(radius), kind="capsule", flat=U(0.7, 1.0) if kind != "eel" else 1.3, side=X)
        head_b = spine[0] if head_first else spine[-1]
        hpos = rig.heads[head_b] if head_first else pts[-1]
        hdir = unit(pts[0] - pts[1]) if head_first else unit(pts[-1] - pts[-2])
        if not head_first:
            head_b = rig.bone(namer("head"), spine[-1], hpos, hpos + hdir * r * 3)
        rig.part(head_b, "ellipsoid", hpos - hdir * r, hpos + hdir * r * 3.2, r * 1.4, r * 0.9, flat=0.7, side=X)
        if kind != "worm" and rng.random() < 0.6:
            jaw = rig.bone(namer("jaw"), head_b, hpos - Y * r * 0.3, hpos + hdir * r * 3 - Y * r * 0.4)
            rig.part(jaw, "cone", rig.heads[jaw], rig.tails[jaw], r * 0.9, flat=0.35, side=X)
            if rng.random() < 0.3:
                tg = rig.bone(namer("tongue"), jaw, hpos + hdir * r * 2.5, hpos + hdir * r * 5)
                rig.part(tg, "capsule", rig.heads[tg], rig.tails[tg], r * 0.12, mat=3)
        return rig
    if kind == "seahorse":
        n = int(rng.integers(6, 13))
        H = U(0.05, 0.4)
        r = H * 0.09
        pts = chain_points(v3(0, H * 0.8, 0), v3(0, -1, 0.2), H, n, bend_axis=X, bend_deg=-300, taper=0.9)
        spine = add_chain(rig, -1, pts, [namer("spine", None, k + 1) for k in range(n)],
                          radii=_radii(r * 1.2, r * 0.3, n), flat=0.8, side=X)
        h0 = pts[0] + v3(0, 0.5, 0.3) * H * 0.06
        head = rig.bone(namer("head"), spine[0], h0, h0 + v3(0, 0.3, 1) * H * 0.25)
        rig.part(head, "cone", h0, rig.tails[head], r * 1.1, r * 0.3, flat=0.7, side=X)
        return rig
    # Fish-like: body chain along -Z from the head.
    L = {"whale": U(4, 15), "dolphin": U(1.5, 3), "shark": U(1.5, 5), "tadpole": U(0.02, 0.08), "fish": np.exp(U(np.log(0.05), np.log(2.0)))}[kind]
    n = int(rng.integers(5, 13)) if kind in ("whale", "dolphin", "shark") else int(rng.integers(3, 9))
    girth = L * {"whale": U(0.1, 0.16), "dolphin": U(0.08, 0.12), "shark": U(0.08, 0.12), "tadpole": 0.25, "fish": U(0.1, 0.3)}[kind]
    deep = kind == "fish"  # fish are tall and thin, cetaceans round
    flat = U(1.2, 2.5) if deep else U(0.8, 1.1)
    y0 = L * 0.3
    bend = U(-25, 25)
    pts = chain_points(v3(0, y0, L * 0.45), v3(0, 0, -1), L * 0.9, n, bend_axis=Y, bend_deg=bend)
    prof = np.sin(np.pi * np.clip(np.linspace(0.05, 1.0, n + 1) ** 0.6, 0, 1)) + 0.15
    if kind == "tadpole":
        prof = np.concatenate([[1.0, 1.0], np.linspace(0.4, 0.05, n - 1)])
    seg_kind = str(rng.choice(["capsule", "capsule", "ellipsoid"]))
    root_mid = rng.random() < 0.35
    names = [namer("spine", None, k + 1) for k in range(n)]
    if root_mid:
        # Root in the middle: one chain forward to the head, one back to the tail.
        m = n // 2
        spine = [0] * n
        spine[m] = p = rig.bone(namer("root"), -1, pts[m], pts[m + 1])
        for k in range(m - 1, -1, -1):
            tail = pts[k - 1] if k > 0 else pts[0] + (pts[0] - pts[1]) * 0.5
            spine[k] = p = rig.bone(names[k], p, pts[k], tail)
        p = spine[m]
        for k in range(m + 1, n):
            spine[k] = p = rig.bone(names[k], p, pts[k], pts[k + 1])
    else:
        spine = add_chain(rig, -1, pts, names)
    for k in range(n):
        rr = girth * prof[k]
        rr1 = girth * prof[k + 1]
        if seg_kind == "ellipsoid":
            a, e = _overlap(pts[k], pts[k + 1], 0.4)
            rig.part(spine[k], "ellipsoid", a, e, max(rr, rr1), flat=flat, side=X)
        else:
            rig.part(spine[k], "capsule", pts[k], pts[k + 1], rr, rr1, flat=flat, side=X)
    head = spine[0]
    hp = pts[0]
    # Nose cap and jaw
    rig.part(head, "ellipsoid", hp - Z * girth * 0.3, hp + Z * girth * 0.9, girth * prof[0] * 0.9, flat=flat * 0.9, side=X)
    if rng.random() < 0.6:
        jaw = rig.bone(namer("jaw"), head, hp - Y * girth * 0.3 * flat, hp + Z * girth * 0.8 - Y * girth * 0.4 * flat)
        rig.part(jaw, "cone", rig.heads[jaw], rig.tails[jaw], girth * 0.4, flat=0.4, side=X)
    tail = spine[-1]
    te = pts[-1]
    tdir = unit(pts[-1] - pts[-2])
    fin_len = L * U(0.12, 0.25)
    if kind in ("whale", "dolphin"):
        for s, sx in SIDES:
            f = rig.bone(namer("fluke", s), tail, te, te + unit(v3(sx, 0, -0.6)) * fin_len)
            rig.part(f, "ellipsoid", te, rig.tails[f], fin_len * 0.3, flat=0.12, side=Z)
    else:
        n_t = int(rng.choice([1, 2]))
        fins = []
        for k in range(n_t):
            dy = (0.7 if k == 0 else -0.7) if n_t == 2 else 0.0
            fins.append(rig.bone(namer("tail_fin", None, k + 1), tail, te, te + unit(tdir + v3(0, dy, 0)) * fin_len))
        grid = np.array([[te + Y * girth * 0.2, te - Y * girth * 0.2],
                         [te + tdir * fin_len + Y * fin_len * 0.7, te + tdir * fin_len - Y * fin_len * 0.7]])
        rig.sheet(fins[0], grid, L * 0.006, cands=fins + [tail], mat=1)
    # Pectoral fins / flippers
    if kind != "tadpole" and rig.room(6):
        nf = int(rng.integers(1, 4)) if kind in ("whale", "dolphin") else int(rng.integers(1, 3))
        host = spine[min(1, n - 1)]
        for s, sx in SIDES:
            p0 = pts[min(1, n)] + v3(sx * girth * 0.7, -girth * 0.3 * flat, 0)
            fp = chain_points(p0, v3(sx, -0.4, -0.6), L * U(0.08, 0.2), nf)
            _leg(rig, host, fp, namer, "fin", s, girth * 0.25, girth * 0.08, kind="ellipsoid", flat=0.2, side=v3(0, 0, 1), mat=1)
    # Dorsal fin
    if kind != "tadpole" and rng.random() < 0.8 and rig.room(2):
        k = n // 2
        b0 = pts[k] + Y * girth * prof[k] * flat * 0.9
        d = rig.bone(namer("dorsal_fin"), spine[k], b0, b0 + unit(v3(0, 1, -0.6)) * L * U(0.06, 0.15))
        grid = np.array([[b0 + Z * L * 0.06, b0 - Z * L * 0.06], [rig.tails[d], rig.tails[d] - Z * L * 0.01]])
        rig.sheet(d, grid, L * 0.005, cands=[d, spine[k]], mat=1)
    return rig


# --- other creatures ------------------------------------------------------------------------


def other_creature(rng: np.random.Generator) -> Rig:
    kind = str(rng.choice(["tentacle_blob", "slime", "tree", "plant", "mushroom", "fruit", "ghost", "snowman", "eyeball"]))
    rig = Rig("other_creature")
    rig.kind = kind
    namer = Namer(rng)
    U = rng.uniform
    S = np.exp(U(np.log(0.2), np.log(3.0)))
    if kind in ("tentacle_blob", "eyeball"):
        r = S * 0.3
        c = v3(0, S * U(0.4, 0.8), 0)
        body = rig.bone(namer("body"), -1, c, c + Y * r)
        rig.part(body, "ellipsoid", c - Y * r, c + Y * r * U(0.9, 1.5), r, flat=U(0.8, 1.1), side=X)
        n_t = int(rng.integers(2, 9))
        n_seg = int(rng.integers(2, 7))
        while not rig.room(n_t * n_seg + 2) and n_seg > 1:
            n_seg -= 1
        down = kind == "tentacle_blob"
        for k in range(n_t):
            ang = 2 * np.pi * k / n_t + U(-0.2, 0.2)
            out = v3(np.cos(ang), 0, np.sin(ang))
            root = c + out * r * 0.7 + (-Y * r * 0.5 if down else Y * r * 0.6)
            d = unit(out * U(0.3, 1.0) + (-Y if down else Y) * U(0.3, 1.0))
            pts = chain_points(root, d, S * U(0.4, 1.0), n_seg, bend_axis=np.cross(d, Y), bend_deg=U(-90, 90), rng=rng, jitter_deg=8)
            if down:
                for p in pts:
                    p[1] = max(p[1], r * 0.05)
            _leg(rig, body, pts, namer, "tentacle", None if k > 25 else str(k + 1), r * 0.18, r * 0.03)
            if not down and rig.room(1):
                eye = rig.bone(namer("eye", None, k + 1), len(rig) - 1, pts[-1], pts[-1] + d * r * 0.3)
                rig.part(eye, "ellipsoid", pts[-1] - d * r * 0.1, pts[-1] + d * r * 0.3, r * 0.15, rigid=True, mat=2)
        if rng.random() < 0.5:
            for s, sx in SIDES:
                e = c + v3(sx * r * 0.35, r * 0.3, r * 0.85)
                rig.part(body, "ellipsoid", e, e + Z * r * 0.2, r * 0.15, rigid=True, mat=2, group="acc", node=rng.random() < 0.5)
        return rig
    if kind == "slime":
        n = int(rng.integers(1, 6))
        h = S * 0.6
        pts = [v3(0, h * k / n, 0) for k in range(n + 1)]
        ch = add_chain(rig, -1, pts, [namer("slime", None, k + 1) for k in range(n)])
        rig.part(ch[0], "ellipsoid", v3(0, 0, 0), v3(0, h * U(0.9, 1.1), 0), S * U(0.35, 0.6), S * U(0.1, 0.35), flat=U(0.8, 1.1), side=X, cands=ch)
        for s, sx in SIDES:
            e = v3(sx * S * 0.12, h * 0.55, S * 0.3)
            rig.part(ch[-1], "ellipsoid", e, e + Z * S * 0.05, S * 0.06, rigid=True, mat=2)
        return rig
    if kind in ("tree", "plant"):
        n_trunk = int(rng.integers(2, 7))
        H = S * U(1.0, 2.0)
        r = H * U(0.04, 0.08)
        pts = chain_points(v3(0, 0, 0), v3(U(-0.1, 0.1), 1, U(-0.1, 0.1)), H * 0.6, n_trunk, rng=rng, jitter_deg=6)
        trunk = _leg(rig, -1, pts, namer, "trunk", None, r, r * 0.5, kind="cyl")

        def branch(parent, start, d, length, rr, depth):
            if depth == 0 or not rig.room(3):
                leaf = start
                rig.part(parent, "ellipsoid", leaf - d * length * 0.2, leaf + d * length * 0.6 + Y * length * 0.2, length * U(0.3, 0.6), mat=1, group="cloth")
                return
            n = int(rng.integers(1, 4))
            bp = chain_points(start, d, length, n, rng=rng, jitter_deg=10, bend_axis=perp(d, Y), bend_deg=U(-30, 30))
            ch = _leg(rig, parent, bp, namer, "branch", None, rr, rr * 0.6, kind="cyl")
            for _ in range(int(rng.integers(1, 3))):
                nd = unit(rot(Y, U(0, 360)) @ unit(d + v3(U(0.3, 0.9), U(0.2, 0.8), 0)))
                branch(ch[-1], bp[-1], nd, length * U(0.5, 0.8), rr * 0.6, depth - 1)
            rig.part(ch[-1], "ellipsoid", bp[-1] - d * length * 0.2, bp[-1] + d * length * 0.5, length * U(0.3, 0.5), mat=1, group="cloth")

        depth = int(rng.integers(1, 4))
        for b in range(int(rng.integers(2, 5))):
            host = trunk[min(len(trunk) - 1, int(rng.integers(n_trunk // 2, n_trunk)))]
            d = unit(rot(Y, U(0, 360)) @ v3(1, U(0.3, 1.2), 0))
            branch(host, rig.heads[host] + (rig.tails[host] - rig.heads[host]) * U(0.3, 1.0), d, H * U(0.15, 0.35), r * 0.5, depth)
        if kind == "plant" and rig.room(4):  # walking plant: two root legs
            for s, sx in SIDES:
                lp = chain_points(v3(sx * r, r, 0), v3(sx, -0.3, 0.2), H * 0.3, 2, bend_axis=Z, bend_deg=sx * 60)
                _leg(rig, trunk[0], lp, namer, "root_leg", s, r * 0.5, r * 0.2, kind="capsule")
        return rig
    if kind == "mushroom":
        H = S
        n = int(rng.integers(2, 4))
        pts = chain_points(v3(0, 0, 0), Y, H * 0.6, n, bend_axis=X, bend_deg=U(-30, 30))
        stem = _leg(rig, -1, pts, namer, "stem", None, H * 0.12, H * 0.09, kind="cyl")
        cap = rig.bone(namer("cap"), stem[-1], pts[-1], pts[-1] + Y * H * 0.3)
        rig.part(cap, "ellipsoid", pts[-1] - Y * H * 0.05, pts[-1] + Y * H * 0.35, H * U(0.3, 0.55), flat=1.0, side=X, mat=1)
        if rng.random() < 0.6 and rig.room(8):
            for s, sx in SIDES:
                ap = chain_points(pts[1] + v3(sx * H * 0.1, 0, 0), v3(sx, -0.5, 0.2), H * 0.3, 2)
                _leg(rig, stem[1 if len(stem) > 1 else 0], ap, namer, "arm", s, H * 0.04, H * 0.025)
                lp = [v3(sx * H * 0.08, H * 0.05, 0), v3(sx * H * 0.1, H * 0.0, H * 0.05)]
                _leg(rig, stem[0], lp, namer, "foot", s, H * 0.05, H * 0.04)
        return rig
    if kind in ("fruit", "snowman", "ghost"):
        r = S * 0.35
        leg_h = r * U(0.3, 1.0) if kind == "fruit" else 0.0
        c = v3(0, leg_h + r, 0)
        body = rig.bone(namer("body" if kind != "ghost" else "root"), -1, c - Y * r * 0.5, c + Y * r)
        if kind == "fruit":
            rig.part(body, "ellipsoid", c - Y * r, c + Y * r * U(0.9, 1.6), r, r * U(0.5, 1.2), flat=U(0.85, 1.1), side=X)
            if rig.room(1):
                st = rig.bone(namer("stem"), body, c + Y * r, c + Y * r * 1.4)
                rig.part(st, "cyl", c + Y * r * 0.9, c + Y * r * 1.4, r * 0.06, mat=1)
                rig.part(st, "ellipsoid", c + Y * r * 1.25, c + Y * r * 1.3 + X * r * 0.6, r * 0.25, flat=0.15, side=Z, mat=1)
        elif kind == "snowman":
            top = body
            rig.part(body, "ellipsoid", c - Y * r, c + Y * r, r)
            c2 = c + Y * r * 1.6
            mid = rig.bone(namer("torso"), body, c + Y * r * 0.8, c2 + Y * r * 0.6)
            rig.part(mid, "ellipsoid", c2 - Y * r * 0.7, c2 + Y * r * 0.7, r * 0.7)
            c3 = c2 + Y * r * 1.1
            top = rig.bone(namer("head"), mid, c2 + Y * r * 0.6, c3 + Y * r * 0.5)
            snow_mid, snow_head = mid, top
            rig.part(top, "ellipsoid", c3 - Y * r * 0.45, c3 + Y * r * 0.45, r * 0.45)
            rig.part(top, "cone", c3 + Z * r * 0.4, c3 + Z * r * 0.9, r * 0.08, mat=2)
            c = c2
        else:  # ghost: body tapering into a tail chain
            rig.part(body, "ellipsoid", c - Y * r * 0.4, c + Y * r, r, flat=0.9, side=X)
            n = int(rng.integers(2, 5))
            tp = chain_points(c - Y * r * 0.8, v3(0, -1, -0.5), S * 0.6, n, bend_axis=X, bend_deg=U(-60, 60))
            for p in tp:
                p[1] = max(p[1], 0.02 * S)
            _leg(rig, body, tp, namer, "tail", None, r * 0.9, r * 0.1, kind="capsule")
        if rig.room(8):
            n_a = int(rng.integers(1, 3))
            for s, sx in SIDES:
                ap = chain_points(c + v3(sx * r * 0.85, 0, 0), v3(sx, U(-0.8, 0.3), 0.1), r * U(0.6, 1.2), n_a)
                arm = _leg(rig, body if kind != "snowman" else snow_mid, ap, namer, "arm", s, r * 0.08, r * 0.05,
                           kind="cyl" if kind == "snowman" else "capsule")
                rig.part(arm[-1], "ellipsoid", ap[-1] - unit(ap[-1] - ap[-2]) * r * 0.05, ap[-1] + unit(ap[-1] - ap[-2]) * r * 0.2, r * 0.1)
                if kind == "fruit":
                    lp = [v3(sx * r * 0.4, leg_h + r * 0.2, 0), v3(sx * r * 0.45, leg_h * 0.5, 0), v3(sx * r * 0.45, 0.0, r * 0.1)]
                    leg = _leg(rig, body, lp, namer, "leg", s, r * 0.09, r * 0.07)
                    rig.part(leg[-1], "ellipsoid", lp[-1] - Z * r * 0.1, lp[-1] + Z * r * 0.25, r * 0.12, flat=0.7, side=X, mat=3)
        if rng.random() < 0.6:
            for s, sx in SIDES:
                e = c + v3(sx * r * 0.35, r * 0.35, r * 0.9)
                if kind == "snowman":
                    e = rig.heads[snow_head] + v3(sx * r * 0.15, r * 0.45, r * 0.38)
                rig.part(body if kind != "snowman" else snow_head, "ellipsoid", e, e + Z * r * 0.12, r * 0.12, rigid=True, mat=2, group="acc")
        return rig
    raise AssertionError(kind)
