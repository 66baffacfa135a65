"""Triangle meshes for the primitive shapes of a [`Part`]: each returns positions,
per-vertex normals and triangles in world space.

Closed shapes are convex, so winding is made outward by a centroid test rather than by
getting every cap's index order right; normals then come from the triangles, which
keeps flat faces sharp (boxes, caps) and curved ones smooth."""

from __future__ import annotations

import numpy as np

from .rig import Part, perp, unit


def _ring_tris(n: int, k0: int, k1: int) -> np.ndarray:
    j = np.arange(n)
    j1 = (j + 1) % n
    a, b, c, d = k0 + j, k0 + j1, k1 + j1, k1 + j
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _fan(n: int, pole: int, k0: int) -> np.ndarray:
    j = np.arange(n)
    return np.stack([np.full(n, pole), k0 + j, k0 + (j + 1) % n], 1)


def lathe(a, b, zs, rs, n: int, side, flat: float, pole0: float | None, pole1: float | None):
    """Surface of revolution around a→b: rings at distances `zs` along the axis with radii
    `rs` (elliptic: `flat` scales the second axis), closed by poles at the given distances."""
    a = np.asarray(a, dtype=np.float64)
    d = unit(np.asarray(b, dtype=np.float64) - a)
    if not np.any(d):
        d = np.array([0.0, 1.0, 0.0])
    u = perp(d, side if side is not None else np.array([1.0, 0.0, 0.0]))
    v = np.cross(d, u)
    th = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    circ = np.cos(th)[:, None] * u + (flat * np.sin(th))[:, None] * v  # (n, 3)
    zs = np.asarray(zs, dtype=np.float64)
    rs = np.asarray(rs, dtype=np.float64)
    rings = a + zs[:, None, None] * d + rs[:, None, None] * circ[None]  # (m, n, 3)
    pos = [rings.reshape(-1, 3)]
    m = len(zs)
    tris = [_ring_tris(n, k * n, (k + 1) * n) for k in range(m - 1)]
    nv = m * n
    if pole0 is not None:
        pos.append((a + d * pole0)[None])
        tris.append(_fan(n, nv, 0))
        nv += 1
    if pole1 is not None:
        pos.append((a + d * pole1)[None])
        tris.append(_fan(n, nv, (m - 1) * n))
        nv += 1
    return np.concatenate(pos), np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)


def _merge(pieces):
    pos, tris, off = [], [], 0
    for p, t in pieces:
        pos.append(p)
        tris.append(t + off)
        off += len(p)
    return np.concatenate(pos), np.concatenate(tris)


def capsule(p: Part, n: int, rings: int):
    L = float(np.linalg.norm(p.b - p.a))
    h = max(2, rings // 3)
    th = np.linspace(0, np.pi / 2, h + 1)[1:]  # excludes the pole
    z0 = -p.r0 * np.cos(th)
    r0 = p.r0 * np.sin(th)
    body = max(0, rings - 2 * h)
    zb = np.linspace(0, L, body + 2)[1:-1]
    rb = np.interp(zb, [0, L if L > 0 else 1], [p.r0, p.r1])
    z1 = L + p.r1 * np.cos(th[::-1])
    r1 = p.r1 * np.sin(th[::-1])
    zs = np.concatenate([z0, zb, z1])
    rs = np.concatenate([r0, rb, r1])
    return lathe(p.a, p.b, zs, rs, n, p.side, p.flat, -p.r0, L + p.r1)


def ellipsoid(p: Part, n: int, rings: int):
    L = float(np.linalg.norm(p.b - p.a))
    m = max(3, rings)
    th = np.linspace(0, np.pi, m + 1)[1:-1]
    zs = L / 2 - L / 2 * np.cos(th)
    # r1 lets eggs and pears: the radius eases from r0 to r1 along the axis.
    rs = np.sin(th) * np.interp(zs, [0, max(L, 1e-9)], [p.r0, p.r1])
    return lathe(p.a, p.b, zs, rs, n, p.side, p.flat, 0.0, L)


def cylinder(p: Part, n: int, rings: int):
    """Tapered cylinder with flat caps; a zero `r1` makes a cone with an apex."""
    L = float(np.linalg.norm(p.b - p.a))
    m = max(2, rings // 2)
    zs = np.linspace(0, L, m)
    rs = np.linspace(p.r0, p.r1, m)
    apex = p.r1 <= 1e-9
    if apex:
        zs, rs = zs[:-1], rs[:-1]
    side = lathe(p.a, p.b, zs, rs, n, p.side, p.flat, None, L if apex else None)
    pieces = [side, lathe(p.a, p.b, [0.0], [p.r0], n, p.side, p.flat, 0.0, None)]
    if not apex:
        pieces.append(lathe(p.a, p.b, [L], [p.r1], n, p.side, p.flat, None, L))
    return _merge(pieces)


def box(p: Part, k: int):
    """Frustum box: half-extents r0 (×flat in depth) at `a`, r1 at `b`; each face a
    (k+1)² grid so flat props still reach a useful vertex count."""
    d = unit(p.b - p.a)
    if not np.any(d):
        d = np.array([0.0, 1.0, 0.0])
    u = perp(d, p.side if p.side is not None else np.array([1.0, 0.0, 0.0]))
    v = np.cross(d, u)
    c = []
    for end, r in ((p.a, p.r0), (p.b, p.r1)):
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            c.append(end + su * r * u + sv * r * p.flat * v)
    c = np.array(c)
    faces = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    t = np.linspace(0, 1, k + 1)
    s, w = np.meshgrid(t, t, indexing="ij")
    s, w = s.reshape(-1, 1), w.reshape(-1, 1)
    i = np.arange(k)
    ii, jj = np.meshgrid(i, i, indexing="ij")
    q = (ii * (k + 1) + jj).reshape(-1)
    quad = np.concatenate([np.stack([q, q + k + 1, q + k + 2], 1), np.stack([q, q + k + 2, q + 1], 1)])
    pieces = []
    for f in faces:
        p0, p1, p2, p3 = c[list(f)]
        pts = (1 - s) * (1 - w) * p0 + s * (1 - w) * p1 + s * w * p2 + (1 - s) * w * p3
        pieces.append((pts, quad))
    return _merge(pieces)


def sheet(p: Part, sub: int):
    """Double-sided slab over a grid of points (wing membranes, capes, fins, leaves).
    `sub` subdivides each grid cell so large sheets bend smoothly under skinning."""
    g = p.grid
    R, C = g.shape[:2]
    if sub > 1:
        # Bilinear refinement of the control grid.
        rr = np.linspace(0, R - 1, (R - 1) * sub + 1)
        cc = np.linspace(0, C - 1, (C - 1) * sub + 1)
        r0 = np.minimum(np.floor(rr).astype(int), R - 2)
        c0 = np.minimum(np.floor(cc).astype(int), C - 2)
        fr = (rr - r0)[:, None, None]
        fc = (cc - c0)[None, :, None]
        g = (
            g[r0][:, c0] * (1 - fr) * (1 - fc)
            + g[r0 + 1][:, c0] * fr * (1 - fc)
            + g[r0][:, c0 + 1] * (1 - fr) * fc
            + g[r0 + 1][:, c0 + 1] * fr * fc
        )
        R, C = g.shape[:2]
    # Grid normals from neighbour differences; the slab is offset along them.
    du = np.gradient(g, axis=1)
    dv = np.gradient(g, axis=0)
    nrm = np.cross(du, dv)
    ln = np.linalg.norm(nrm, axis=2, keepdims=True)
    fallback = perp(g[-1, -1] - g[0, 0], np.array([0.0, 1.0, 0.0]))
    nrm = np.where(ln > 1e-12, nrm / np.maximum(ln, 1e-12), fallback)
    top = (g + nrm * p.thick / 2).reshape(-1, 3)
    bot = (g - nrm * p.thick / 2).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(R - 1), np.arange(C - 1), indexing="ij")
    q = (i * C + j).reshape(-1)
    t_top = np.concatenate([np.stack([q, q + 1, q + C + 1], 1), np.stack([q, q + C + 1, q + C], 1)])
    n = R * C
    t_bot = t_top[:, ::-1] + n
    return np.concatenate([top, bot]), np.concatenate([t_top, t_bot])


def vertex_normals(pos: np.ndarray, tris: np.ndarray) -> np.ndarray:
    a, b, c = pos[tris[:, 0]], pos[tris[:, 1]], pos[tris[:, 2]]
    fn = np.cross(b - a, c - a)
    n = np.zeros_like(pos)
    for k in range(3):
        np.add.at(n, tris[:, k], fn)
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    # Vertices with no area around them (never expected) point away from the centre so
    # the file still has unit normals everywhere.
    away = pos - pos.mean(0)
    la = np.linalg.norm(away, axis=1, keepdims=True)
    away = np.where(la > 1e-12, away / np.maximum(la, 1e-12), np.array([0.0, 1.0, 0.0]))
    return np.where(ln > 1e-20, n / np.maximum(ln, 1e-30), away)


def orient_outward(pos: np.ndarray, tris: np.ndarray) -> np.ndarray:
    c = pos.mean(0)
    a, b, cc = pos[tris[:, 0]], pos[tris[:, 1]], pos[tris[:, 2]]
    fn = np.cross(b - a, cc - a)
    inward = np.einsum("ij,ij->i", fn, (a + b + cc) / 3 - c) < 0
    t = tris.copy()
    t[inward] = t[inward][:, ::-1]
    return t


def build(p: Part, n: int, rings: int, box_k: int, sheet_sub: int):
    """Positions, normals, triangles of one part."""
    if p.kind == "sheet":
        pos, tris = sheet(p, sheet_sub)
        return pos, vertex_normals(pos, tris), tris
    if p.kind == "capsule":
        pos, tris = capsule(p, n, rings)
    elif p.kind == "ellipsoid":
        pos, tris = ellipsoid(p, n, rings)
    elif p.kind in ("cyl", "cone"):
        if p.kind == "cone":
            p = Part(**{**p.__dict__, "r1": 0.0})
        pos, tris = cylinder(p, n, rings)
    elif p.kind == "box":
        pos, tris = box(p, box_k)
    else:
        raise ValueError(p.kind)
    tris = orient_outward(pos, tris)
    return pos, vertex_normals(pos, tris), tris


def vertex_estimate(p: Part, n: int, rings: int, box_k: int, sheet_sub: int) -> int:
    if p.kind == "box":
        return 6 * (box_k + 1) ** 2
    if p.kind == "sheet":
        R, C = p.grid.shape[:2]
        return 2 * ((R - 1) * sheet_sub + 1) * ((C - 1) * sheet_sub + 1)
    if p.kind == "capsule":
        h = max(2, rings // 3)
        return n * (2 * h + max(0, rings - 2 * h)) + 2
    if p.kind == "ellipsoid":
        return n * (max(3, rings) - 1) + 2
    return n * (max(2, rings // 2) + 2) + 2


def flat_vertex_estimate(p: Part, n: int, rings: int, box_k: int, sheet_sub: int) -> int:
    """Vertices once every triangle gets its own corners (flat shading; sheets stay smooth)."""
    if p.kind == "sheet":
        return vertex_estimate(p, n, rings, box_k, sheet_sub)
    if p.kind == "box":
        return 3 * 12 * box_k * box_k
    # A closed triangulated surface has about two triangles per vertex.
    return 3 * 2 * vertex_estimate(p, n, rings, box_k, sheet_sub)
