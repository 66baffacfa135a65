"""Robots and rigged props: rigid parts, each vertex bound 1.0 to one bone, the way
mechanical rigs are skinned."""

from __future__ import annotations

import numpy as np

from .naming import Namer
from .rig import X, Y, Z, Rig, chain_points, lerp, rot, unit, v3

SIDES = (("L", 1.0), ("R", -1.0))


def _box(rig, b, a, e, w, flat=1.0, side=X, **kw):
    return rig.part(b, "box", a, e, w, kw.pop("w1", w), flat=flat, side=side, **kw)


def mech(rng, rig: Rig, namer: Namer):
    U = rng.uniform
    H = U(1.0, 8.0)
    leg_len = H * U(0.35, 0.5)
    torso = H * U(0.25, 0.35)
    w = H * U(0.12, 0.22)
    hips_p = v3(0, leg_len, 0)
    root = -1
    if rng.random() < 0.3:
        root = rig.bone(namer("root"), -1, v3(0, 0, 0), hips_p)
    pelvis = rig.bone(namer("pelvis"), root, hips_p, hips_p + Y * torso * 0.3)
    _box(rig, pelvis, hips_p - Y * H * 0.05, hips_p + Y * H * 0.05, w * 0.8, flat=0.7)
    n_t = int(rng.integers(1, 3))
    t_pts = [hips_p + Y * torso * (0.2 + 0.8 * k / n_t) for k in range(n_t + 1)]
    prev = pelvis
    for k in range(n_t):
        prev = rig.bone(namer("torso", None, k + 1), prev, t_pts[k], t_pts[k + 1])
        _box(rig, prev, t_pts[k], t_pts[k + 1], w * (0.8 + 0.4 * (k + 1) / n_t), w1=w * (1.0 + 0.3 * (k + 1) / n_t), flat=U(0.5, 0.9))
    chest = prev
    top = t_pts[-1]
    if rng.random() < 0.8:
        hd = rig.bone(namer("head"), chest, top, top + Y * H * 0.1)
        _box(rig, hd, top, top + Y * H * U(0.06, 0.14), w * U(0.3, 0.6), flat=U(0.8, 1.3))
        if rng.random() < 0.5:
            rig.part(hd, "cyl", top + Y * H * 0.05 + Z * w * 0.3, top + Y * H * 0.05 + Z * w * 0.6, w * 0.08, mat=2)
    chicken = rng.random() < 0.3
    arm_segs = int(rng.integers(2, 5))
    for s, sx in SIDES:
        sh = top - Y * torso * 0.15 + X * sx * w * 1.2
        a = rng.uniform(0, 70)
        d = unit(v3(sx * np.cos(np.radians(a)), -np.sin(np.radians(a)), 0.15))
        pts = chain_points(sh, d, H * U(0.3, 0.45), arm_segs, bend_axis=v3(0, 0, sx), bend_deg=-sx * U(0, 30))
        prev = chest
        for k in range(arm_segs):
            prev = rig.bone(namer("arm", s, k + 1), prev, pts[k], pts[k + 1])
            _box(rig, prev, pts[k], pts[k + 1], H * U(0.03, 0.06), flat=U(0.7, 1.2), side=Z)
            rig.part(prev, "cyl", pts[k] - Z * H * 0.04, pts[k] + Z * H * 0.04, H * 0.045, mat=1, side=X)
        if rng.random() < 0.4:  # arm gun
            _box(rig, prev, pts[-1], pts[-1] + Z * H * 0.2, H * 0.03, mat=2, side=X)
        hip = hips_p + X * sx * w * 0.7 - Y * H * 0.03
        if chicken:
            knee = v3(sx * w * 0.9, leg_len * 0.6, H * 0.12)
            ankle = v3(sx * w * 0.9, leg_len * 0.2, -H * 0.08)
        else:
            knee = v3(sx * w * 0.75, leg_len * 0.52, H * 0.03)
            ankle = v3(sx * w * 0.75, H * 0.04, 0)
        toe = v3(ankle[0], 0.0, H * 0.12)
        pts = [hip, knee, ankle, toe]
        prev = pelvis
        for k in range(3):
            prev = rig.bone(namer("leg", s, k + 1), prev, pts[k], pts[k + 1])
            if k < 2:
                _box(rig, prev, pts[k], pts[k + 1], H * U(0.04, 0.07), flat=U(0.7, 1.2), side=X)
            else:
                _box(rig, prev, ankle + v3(0, -ankle[1] * 0.5, -H * 0.05), toe + v3(0, ankle[1] * 0.1, 0), H * 0.05, flat=0.5, side=X)


def spider_bot(rng, rig, namer):
    U = rng.uniform
    S = U(0.4, 3.0)
    c = v3(0, S * 0.5, 0)
    body = rig.bone(namer("body"), -1, c, c + Y * S * 0.2)
    rig.part(body, str(rng.choice(["box", "cyl"])), c - Y * S * 0.1, c + Y * S * 0.12, S * 0.35, flat=U(0.7, 1.0), side=X)
    n = int(rng.choice([4, 6, 8]))
    segs = int(rng.integers(2, 4))
    for k in range(n):
        ang = 2 * np.pi * (k + 0.5) / n
        out = v3(np.cos(ang), 0, np.sin(ang))
        root = c + out * S * 0.35
        knee = root + out * S * 0.35 + Y * S * 0.25
        foot = v3(*(root + out * S * 0.8)[:1], 0.0, *(root + out * S * 0.8)[2:])
        pts = [root, knee, foot] if segs == 2 else [root, root + out * S * 0.12, knee, foot]
        prev = body
        for j in range(len(pts) - 1):
            prev = rig.bone(namer("leg", None, k * 10 + j + 1), prev, pts[j], pts[j + 1])
            _box(rig, prev, pts[j], pts[j + 1], S * 0.04, flat=1.0, side=Y)
    if rng.random() < 0.6:
        t = rig.bone(namer("turret"), body, c + Y * S * 0.12, c + Y * S * 0.3)
        rig.part(t, "cyl", c + Y * S * 0.12, c + Y * S * 0.25, S * 0.15, side=X, mat=1)
        g = rig.bone(namer("gun"), t, c + Y * S * 0.2, c + Y * S * 0.2 + Z * S * 0.4)
        rig.part(g, "cyl", rig.heads[g], rig.tails[g], S * 0.03, side=X, mat=2)


def chest(rng, rig, namer):
    U = rng.uniform
    w, d, h = U(0.3, 1.2), U(0.2, 0.7), U(0.2, 0.6)
    root = -1
    if rng.random() < 0.5:
        root = rig.bone(namer("root"), -1, v3(0, 0, 0), Y * h * 0.5)
    base = rig.bone(namer("base"), root, v3(0, 0, 0) if root < 0 else Y * h * 0.2, Y * h)
    _box(rig, base, v3(0, 0, 0), v3(0, h, 0), w / 2, flat=d / w)
    hinge = v3(0, h, -d / 2)
    lid = rig.bone(namer("lid"), base, hinge, hinge + Z * d)
    if rng.random() < 0.5:
        rig.part(lid, "cyl", hinge + v3(-w / 2, 0, d / 2), hinge + v3(w / 2, 0, d / 2), d / 2, flat=U(0.3, 1.0), side=Y, mat=1)
    else:
        _box(rig, lid, hinge + v3(0, 0, 0), hinge + v3(0, h * 0.3, 0), w / 2, w1=w / 2 * 0.98, flat=d / w, mat=1)
    if root < 0 and rng.random() < 0.5:  # base, lid and at most one more bone
        lk = rig.bone(namer("lock"), lid, hinge + v3(0, 0, d), hinge + v3(0, -h * 0.15, d))
        _box(rig, lk, hinge + v3(0, 0.02 * h, d), hinge + v3(0, -h * 0.15, d), w * 0.06, flat=0.4, mat=2)


def gun(rng, rig, namer):
    U = rng.uniform
    L = U(0.15, 1.2)
    body = rig.bone(namer("gun" if rng.random() < 0.5 else "body"), -1, v3(0, 0, 0), Z * L * 0.5)
    _box(rig, body, v3(0, 0, -L * 0.3), v3(0, 0, L * 0.5), L * 0.05, flat=U(1.5, 2.5), side=X)
    grip = v3(0, -L * 0.1, -L * 0.2)
    _box(rig, body, v3(0, -L * 0.02, -L * 0.2), v3(0, -L * 0.25, -L * 0.27), L * 0.04, flat=1.6, side=X)
    parts = ["slide", "trigger", "magazine", "hammer", "barrel", "bolt", "scope"]
    chosen = [p for p in parts if rng.random() < 0.6] or ["trigger"]
    for p in chosen:
        if p == "slide":
            b = rig.bone(namer(p), body, v3(0, L * 0.12, -L * 0.25), v3(0, L * 0.12, L * 0.45))
            _box(rig, b, rig.heads[b], rig.tails[b], L * 0.045, flat=0.8, side=X, mat=1)
        elif p == "trigger":
            b = rig.bone(namer(p), body, v3(0, -L * 0.03, -L * 0.08), v3(0, -L * 0.12, -L * 0.1))
            _box(rig, b, rig.heads[b], rig.tails[b], L * 0.01, flat=1.0, side=X, mat=2)
        elif p == "magazine":
            b = rig.bone(namer(p), body, grip, grip - Y * L * 0.25)
            _box(rig, b, grip + Y * L * 0.05, grip - Y * L * 0.3, L * 0.03, flat=1.6, side=X, mat=2)
        elif p == "hammer":
            b = rig.bone(namer(p), body, v3(0, L * 0.1, -L * 0.3), v3(0, L * 0.16, -L * 0.34))
            _box(rig, b, rig.heads[b], rig.tails[b], L * 0.012, side=X, mat=2)
        elif p == "barrel":
            b = rig.bone(namer(p), body, v3(0, L * 0.05, L * 0.4), v3(0, L * 0.05, L * U(0.6, 1.0)))
            rig.part(b, "cyl", rig.heads[b], rig.tails[b], L * 0.025, side=X, mat=1)
        elif p == "bolt":
            b = rig.bone(namer(p), body, v3(L * 0.05, L * 0.08, 0), v3(L * 0.12, L * 0.08, 0))
            rig.part(b, "cyl", rig.heads[b], rig.tails[b], L * 0.012, side=Y, mat=2)
        else:
            b = rig.bone(namer(p), body, v3(0, L * 0.2, -L * 0.1), v3(0, L * 0.2, L * 0.2))
            rig.part(b, "cyl", rig.heads[b], rig.tails[b], L * 0.035, side=X, mat=1)


def vehicle(rng, rig, namer, tank: bool):
    U = rng.uniform
    L = U(2.0, 8.0)
    W = L * U(0.4, 0.55)
    Hh = L * U(0.15, 0.25)
    wr = L * U(0.07, 0.12)
    body = rig.bone(namer("body"), -1, v3(0, wr + Hh * 0.5, 0), v3(0, wr + Hh * 0.5, L * 0.5))
    _box(rig, body, v3(0, wr + Hh * 0.5, -L / 2), v3(0, wr + Hh * 0.5, L / 2), W / 2, flat=Hh / W)
    n_w = int(rng.choice([2, 3, 4])) if tank else 2
    for s, sx in SIDES:
        for k in range(n_w):
            z = lerp(-L * 0.38, L * 0.38, k / (n_w - 1))
            c = v3(sx * W * 0.5, wr, z)
            b = rig.bone(namer("wheel", s, k + 1), body, c, c + X * sx * wr * 0.5)
            rig.part(b, "cyl", c - X * sx * wr * 0.25, c + X * sx * wr * 0.35, wr, side=Y, mat=1)
    top = wr + Hh
    if tank:
        t = rig.bone(namer("turret"), body, v3(0, top, 0), v3(0, top + Hh * 0.6, 0))
        rig.part(t, str(rng.choice(["cyl", "box"])), v3(0, top, 0), v3(0, top + Hh * 0.6, 0), W * 0.32, flat=U(0.8, 1.0), side=X, mat=1)
        g = rig.bone(namer("barrel"), t, v3(0, top + Hh * 0.3, W * 0.3), v3(0, top + Hh * 0.3, W * 0.3 + L * U(0.4, 0.7)))
        rig.part(g, "cyl", rig.heads[g], rig.tails[g], L * 0.025, side=X, mat=2)
        if rng.random() < 0.5:
            h = rig.bone(namer("hatch"), t, v3(0, top + Hh * 0.6, -W * 0.1), v3(0, top + Hh * 0.6, W * 0.1))
            rig.part(h, "cyl", rig.heads[h], rig.heads[h] + Y * Hh * 0.05, W * 0.1, side=X, mat=2)
    else:
        cab = v3(0, top, -L * 0.05)
        _box(rig, body, cab, cab + Y * Hh * 0.8, W * 0.45, w1=W * 0.4, flat=1.2)
        for s, sx in SIDES:
            if rng.random() < 0.7:
                hinge = v3(sx * W * 0.5, top, L * 0.15)
                dr = rig.bone(namer("door", s), body, hinge, hinge - Z * L * 0.3)
                _box(rig, dr, hinge - Z * 0.01 * L, hinge - Z * L * 0.3, Hh * 0.4, flat=0.08, side=Y, mat=2)
        if rng.random() < 0.5:
            sw = rig.bone(namer("steering_wheel"), body, v3(W * 0.2, top + Hh * 0.3, L * 0.05), v3(W * 0.2, top + Hh * 0.35, L * 0.0))
            rig.part(sw, "cyl", rig.heads[sw], rig.heads[sw] + Z * 0.02 * L, L * 0.04, side=X, mat=2)


def lever(rng, rig, namer):
    U = rng.uniform
    s = U(0.2, 1.5)
    base = rig.bone(namer("base"), -1, v3(0, 0, 0), Y * s * 0.2)
    _box(rig, base, v3(0, 0, 0), v3(0, s * 0.15, 0), s * 0.3, flat=U(0.5, 1.0))
    tilt = U(-40, 40)
    d = rot(X, tilt) @ Y
    arm = rig.bone(namer("lever"), base, Y * s * 0.15, Y * s * 0.15 + d * s)
    rig.part(arm, "cyl", rig.heads[arm], rig.tails[arm], s * 0.03, mat=1)
    if rng.random() < 0.7:
        k = rig.bone(namer("knob"), arm, rig.tails[arm], rig.tails[arm] + d * s * 0.1)
        rig.part(k, "ellipsoid", rig.tails[arm] - d * s * 0.05, rig.tails[arm] + d * s * 0.12, s * 0.07, mat=2)


def door(rng, rig, namer):
    U = rng.uniform
    h, w = U(1.8, 3.0), U(0.8, 1.2)
    double = rng.random() < 0.3
    frame = rig.bone(namer("frame"), -1, v3(0, 0, 0), Y * h)
    t = w * 0.08
    tw = w * (2 if double else 1)
    _box(rig, frame, v3(-tw / 2 - t, 0, 0), v3(-tw / 2 - t, h + t, 0), t, flat=1.5, side=X)
    _box(rig, frame, v3(tw / 2 + t, 0, 0), v3(tw / 2 + t, h + t, 0), t, flat=1.5, side=X)
    _box(rig, frame, v3(-tw / 2 - t, h + t, 0), v3(tw / 2 + t, h + t, 0), t, flat=1.5, side=Y)
    for k in range(2 if double else 1):
        sx = 1 if k == 0 else -1
        hinge = v3(-sx * tw / 2, h / 2, 0)
        panel = rig.bone(namer("door", ("L", "R")[k] if double else None), frame, hinge, hinge + X * sx * w)
        _box(rig, panel, hinge + X * sx * 0.01, hinge + X * sx * w * 0.98, h * 0.49, flat=0.04, side=Y, mat=1)
        if rng.random() < 0.8:
            hp = hinge + X * sx * w * 0.85 + Z * t
            hb = rig.bone(namer("handle", ("L", "R")[k] if double else None), panel, hp, hp + Z * t)
            rig.part(hb, "cyl", hp, hp + Z * t * 1.5, w * 0.04, side=X, mat=2)


def lamp_arm(rng, rig, namer):
    U = rng.uniform
    s = U(0.3, 4.0)
    base = rig.bone(namer("base"), -1, v3(0, 0, 0), Y * s * 0.1)
    rig.part(base, "cyl", v3(0, 0, 0), Y * s * 0.08, s * 0.2)
    n = int(rng.integers(2, 6))
    pts = chain_points(Y * s * 0.08, v3(U(-0.3, 0.3), 1, U(-0.3, 0.3)), s, n, bend_axis=X, bend_deg=U(-150, 150))
    prev = base
    for k in range(n):
        prev = rig.bone(namer("arm", None, k + 1), prev, pts[k], pts[k + 1])
        _box(rig, prev, pts[k], pts[k + 1], s * 0.03, flat=U(0.5, 1.0), side=X)
        rig.part(prev, "cyl", pts[k] - X * s * 0.04, pts[k] + X * s * 0.04, s * 0.045, side=Y, mat=1)
    hd = rig.bone(namer("head"), prev, pts[-1], pts[-1] + unit(pts[-1] - pts[-2]) * s * 0.2)
    rig.part(hd, "cone" if rng.random() < 0.5 else "cyl", rig.tails[hd], pts[-1], s * 0.15, s * 0.05, mat=2)


def rotor(rng, rig, namer):
    U = rng.uniform
    h = U(0.5, 10.0)
    base = rig.bone(namer("base"), -1, v3(0, 0, 0), Y * h)
    rig.part(base, "cyl", v3(0, 0, 0), Y * h, h * 0.08, h * 0.04)
    hub_p = v3(0, h, h * 0.06)
    hub = rig.bone(namer("rotor"), base, hub_p, hub_p + Z * h * 0.1)
    rig.part(hub, "cyl", hub_p, hub_p + Z * h * 0.1, h * 0.05, side=X, mat=1)
    n = int(rng.integers(2, 7))
    L = h * U(0.3, 0.6)
    per_blade = rng.random() < 0.7
    for k in range(n):
        ang = 360.0 * k / n
        d = rot(Z, ang) @ Y
        b = rig.bone(namer("blade", None, k + 1), hub, hub_p + Z * h * 0.05, hub_p + Z * h * 0.05 + d * L) if per_blade else hub
        _box(rig, b, hub_p + Z * h * 0.05, hub_p + Z * h * 0.05 + d * L, h * 0.05, w1=h * 0.03, flat=0.15, side=rot(Z, ang) @ X, mat=2)


def drone(rng, rig, namer):
    U = rng.uniform
    s = U(0.2, 1.5)
    body = rig.bone(namer("body"), -1, Y * s * 0.2, Y * s * 0.3)
    _box(rig, body, Y * s * 0.12, Y * s * 0.28, s * 0.2, flat=U(0.8, 1.2))
    n = int(rng.choice([4, 6]))
    for k in range(n):
        ang = 2 * np.pi * (k + 0.5) / n
        out = v3(np.cos(ang), 0, np.sin(ang))
        a = rig.bone(namer("arm", None, k + 1), body, Y * s * 0.2 + out * s * 0.15, Y * s * 0.2 + out * s * 0.6)
        _box(rig, a, rig.heads[a], rig.tails[a], s * 0.03, side=Y)
        p = rig.tails[a] + Y * s * 0.05
        r = rig.bone(namer("propeller", None, k + 1), a, p, p + Y * s * 0.05)
        rig.part(r, "cyl", p, p + Y * s * 0.01, s * 0.25, mat=2)


def crate(rng, rig, namer):
    U = rng.uniform
    s = U(0.3, 2.0)
    b = rig.bone(namer(str(rng.choice(["root", "crate", "barrel", "rock", "prop"]))), -1, v3(0, 0, 0), Y * s)
    if rng.random() < 0.5:
        _box(rig, b, v3(0, 0, 0), v3(0, s, 0), s * U(0.3, 0.6), flat=U(0.7, 1.3))
    else:
        rig.part(b, "cyl", v3(0, 0, 0), v3(0, s, 0), s * U(0.25, 0.45), flat=1.0, side=X)


def robot_prop(rng: np.random.Generator) -> Rig:
    kind = str(rng.choice(["mech", "mech", "spider_bot", "chest", "gun", "tank", "car", "lever", "door", "lamp_arm", "rotor", "drone", "crate"],
                          p=[0.12, 0.08, 0.08, 0.1, 0.1, 0.08, 0.08, 0.07, 0.07, 0.07, 0.06, 0.05, 0.04]))
    rig = Rig("robot_prop")
    rig.kind = kind
    rig.rigid = True
    namer = Namer(rng)
    if kind == "mech":
        mech(rng, rig, namer)
    elif kind == "spider_bot":
        spider_bot(rng, rig, namer)
    elif kind == "chest":
        chest(rng, rig, namer)
    elif kind == "gun":
        gun(rng, rig, namer)
    elif kind in ("tank", "car"):
        vehicle(rng, rig, namer, kind == "tank")
    elif kind == "lever":
        lever(rng, rig, namer)
    elif kind == "door":
        door(rng, rig, namer)
    elif kind == "lamp_arm":
        lamp_arm(rng, rig, namer)
    elif kind == "rotor":
        rotor(rng, rig, namer)
    elif kind == "drone":
        drone(rng, rig, namer)
    else:
        crate(rng, rig, namer)
    return rig
