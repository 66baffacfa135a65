"""The in-memory character a builder fills: bones in world space plus the shapes that
become its mesh. Everything here is in the displayed frame (glTF Y-up, metres, +Z
forward, the character's left on +X); node-space conversion happens only when writing."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

X = np.array([1.0, 0.0, 0.0])
Y = np.array([0.0, 1.0, 0.0])
Z = np.array([0.0, 0.0, 1.0])

# Skeletons above this are trimmed of optional extras by the builders; rigserve's data set
# skips anything over 128 bones, and real rigs in the target range rarely exceed 80.
MAX_BONES = 80


def v3(x, y, z) -> np.ndarray:
    return np.array([x, y, z], dtype=np.float64)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 1e-12 else v * 0.0


def rot(axis, deg) -> np.ndarray:
    """3×3 rotation about `axis` by `deg` degrees (right-handed)."""
    a = unit(axis)
    t = np.radians(deg)
    c, s = np.cos(t), np.sin(t)
    x, y, z = a
    return np.array(
        [
            [c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
            [y * x * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
            [z * x * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)],
        ]
    )


def perp(d, hint) -> np.ndarray:
    """A unit vector perpendicular to `d`, as close to `hint` as possible."""
    d = unit(d)
    h = np.asarray(hint, dtype=np.float64)
    u = h - d * np.dot(h, d)
    if np.linalg.norm(u) < 1e-6 * max(1.0, np.linalg.norm(h)):
        for alt in (X, Z, Y):
            u = alt - d * np.dot(alt, d)
            if np.linalg.norm(u) > 1e-3:
                break
    return unit(u)


def mirror(p) -> np.ndarray:
    return np.array([-p[0], p[1], p[2]], dtype=np.float64)


@dataclass
class Part:
    """One primitive shape. `a`→`b` is its main axis; `r0`/`r1` the half-widths at each end
    along `side`, and `flat` scales the other cross-section axis."""

    bone: int
    kind: str  # capsule | ellipsoid | cyl | cone | box | sheet
    a: np.ndarray
    b: np.ndarray
    r0: float
    r1: float
    flat: float = 1.0
    side: np.ndarray | None = None
    rigid: bool = False
    mat: int = 0
    cands: list[int] | None = None
    grid: np.ndarray | None = None  # sheet: (rows, cols, 3) points
    thick: float = 0.0
    group: str = "body"  # body | cloth | acc; multi-part files split primitives by it
    node: bool = False  # accessory written as an unskinned mesh under the bone's node


@dataclass
class Rig:
    category: str
    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    heads: list[np.ndarray] = field(default_factory=list)
    tails: list[np.ndarray | None] = field(default_factory=list)
    deform: list[bool] = field(default_factory=list)
    parts: list[Part] = field(default_factory=list)
    rigid: bool = False  # every vertex 1.0 to one bone (props, blocky low-poly mobs)
    kind: str = ""  # sub-type, for logs and tests

    def __len__(self) -> int:
        return len(self.names)

    def bone(self, name: str, parent: int, head, tail=None, deform: bool = True) -> int:
        if parent >= len(self.names):
            raise ValueError(f"parent {parent} of {name} does not exist yet")
        # Real exporters never emit two nodes named alike within a rig; keep names unique.
        base, k = name, 1
        while name in self._name_set():
            k += 1
            name = f"{base}_{k}"
        self.names.append(name)
        self.parents.append(parent)
        self.heads.append(np.asarray(head, dtype=np.float64).copy())
        self.tails.append(None if tail is None else np.asarray(tail, dtype=np.float64).copy())
        self.deform.append(deform)
        return len(self.names) - 1

    def _name_set(self):
        return set(self.names)

    def room(self, n: int) -> bool:
        return len(self.names) + n <= MAX_BONES

    def part(self, bone: int, kind: str, a, b, r0: float, r1: float | None = None, **kw) -> Part:
        p = Part(
            bone=bone,
            kind=kind,
            a=np.asarray(a, dtype=np.float64),
            b=np.asarray(b, dtype=np.float64),
            r0=float(r0),
            r1=float(r0 if r1 is None else r1),
            **kw,
        )
        if self.rigid:
            p.rigid = True
        self.parts.append(p)
        return p

    def sheet(self, bone: int, grid, thick: float, **kw) -> Part:
        g = np.asarray(grid, dtype=np.float64)
        p = Part(bone=bone, kind="sheet", a=g[0, 0], b=g[-1, -1], r0=thick, r1=thick, grid=g, thick=thick, **kw)
        if self.rigid:
            p.rigid = True
        self.parts.append(p)
        return p

    def children(self) -> list[list[int]]:
        out: list[list[int]] = [[] for _ in self.names]
        for i, p in enumerate(self.parents):
            if p >= 0:
                out[p].append(i)
        return out

    def finalize(self) -> None:
        """Fills missing tails: a bone points at its first child, a leaf continues its
        parent's direction, so every bone has a segment for weighting and orientation."""
        kids = self.children()
        scale = self.extent()
        for i in range(len(self.names)):
            if self.tails[i] is not None and np.linalg.norm(self.tails[i] - self.heads[i]) > 1e-6:
                continue
            h = self.heads[i]
            t = None
            for c in kids[i]:
                if np.linalg.norm(self.heads[c] - h) > 1e-6:
                    t = self.heads[c]
                    break
            if t is None:
                p = self.parents[i]
                d = h - self.heads[p] if p >= 0 else Y
                if np.linalg.norm(d) < 1e-6:
                    d = Y * 0.1 * scale
                t = h + d * 0.5
            self.tails[i] = np.asarray(t, dtype=np.float64)

    def extent(self) -> float:
        if not self.heads:
            return 1.0
        h = np.array(self.heads)
        e = float(np.linalg.norm(h.max(0) - h.min(0)))
        return e if e > 1e-6 else 1.0

    def check(self) -> None:
        n = len(self.names)
        assert 1 <= n, "no bones"
        assert len(set(self.names)) == n, "duplicate bone names"
        for i, p in enumerate(self.parents):
            assert p < i, f"bone {i} parent {p} not before it"
        assert all(np.all(np.isfinite(h)) for h in self.heads)


def chain_points(start, direction, length: float, n: int, bend_axis=None, bend_deg: float = 0.0,
                 rng: np.random.Generator | None = None, jitter_deg: float = 0.0, taper: float = 1.0):
    """n+1 points of a chain of n segments that curls by `bend_deg` in total about
    `bend_axis`; segment lengths shrink geometrically by `taper`."""
    pts = [np.asarray(start, dtype=np.float64)]
    d = unit(direction)
    if taper == 1.0:
        segs = [length / n] * n
    else:
        w = np.array([taper**k for k in range(n)])
        segs = list(length * w / w.sum())
    step = bend_deg / max(n, 1)
    for k in range(n):
        if bend_axis is not None and k > 0:
            d = rot(bend_axis, step) @ d
        if rng is not None and jitter_deg > 0:
            d = rot(perp(d, rng.normal(size=3)), rng.normal() * jitter_deg) @ d
        pts.append(pts[-1] + d * segs[k])
    return pts


def lerp(a, b, t):
    return a + (b - a) * t


def add_chain(rig: Rig, parent: int, pts, names, radii=None, kind: str = "capsule", flat: float = 1.0,
              side=None, mat: int = 0, group: str = "body", end_bone: str | None = None, **kw) -> list[int]:
    """Bones at pts[0..n-1], the last one's tail at pts[n]; with `radii` (n+1 values), one
    shape per bone. `end_bone` adds a non-deforming leaf at pts[n], like exporters'
    `_End` bones."""
    out = []
    p = parent
    n = len(pts) - 1
    for k in range(n):
        b = rig.bone(names[k], p, pts[k], pts[k + 1])
        out.append(b)
        if radii is not None:
            rig.part(b, kind, pts[k], pts[k + 1], radii[k], radii[k + 1], flat=flat, side=side, mat=mat, group=group, **kw)
        p = b
    if end_bone is not None:
        e = rig.bone(end_bone, p, pts[n], pts[n] + (pts[n] - pts[n - 1]) * 0.3, deform=False)
        out.append(e)
    return out
