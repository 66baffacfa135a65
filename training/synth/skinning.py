"""Skin weights for generated parts.

Organic parts blend between their own bone and its immediate neighbours by distance to
the bone segments, so influence changes only near joints the way artist weights do;
rigid parts (props, blocky mobs, most accessories) take 1.0 from their bone."""

from __future__ import annotations

import numpy as np

MAX_INFLUENCES = 4


def segment_distance(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances from each point (V,3) to each segment a[k]→b[k]; returns (V, K)."""
    ab = b - a  # (K,3)
    ap = pts[:, None, :] - a[None]  # (V,K,3)
    den = np.maximum(np.einsum("kj,kj->k", ab, ab), 1e-18)
    t = np.clip(np.einsum("vkj,kj->vk", ap, ab) / den, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(pts[:, None, :] - closest, axis=2)


def candidates(bone: int, parents, kids, deform) -> list[int]:
    c = [bone]
    p = parents[bone]
    if p >= 0 and deform[p]:
        c.append(p)
    c.extend(k for k in kids[bone] if deform[k])
    return c


def part_weights(pts: np.ndarray, bone: int, cands: list[int], heads: np.ndarray, tails: np.ndarray,
                 width: float, rigid: bool):
    """(V,4) joint indices and (V,4) float64 weights summing to 1, largest first."""
    V = len(pts)
    joints = np.zeros((V, MAX_INFLUENCES), dtype=np.int64)
    weights = np.zeros((V, MAX_INFLUENCES), dtype=np.float64)
    if rigid or len(cands) == 1:
        joints[:, 0] = bone
        weights[:, 0] = 1.0
        return joints, weights
    # Builders may name a bone twice (a body part listing its own chain); glTF forbids a
    # joint appearing twice in one vertex's influences.
    cands = np.asarray(list(dict.fromkeys([bone] + list(cands))))
    if len(cands) == 1:
        joints[:, 0] = bone
        weights[:, 0] = 1.0
        return joints, weights
    d = segment_distance(pts, heads[cands], tails[cands])
    # Bias toward the part's own bone so a limb stays bound to it away from the joints
    # even where a neighbour's segment passes closer (a thick torso around the shoulders).
    d[:, 0] -= 0.25 * width
    rel = (d - d.min(1, keepdims=True)) / max(width, 1e-9)
    w = np.exp(-(rel**2))
    w[w < 0.02] = 0.0
    k = min(MAX_INFLUENCES, len(cands))
    order = np.argsort(-w, axis=1, kind="stable")[:, :k]
    top = np.take_along_axis(w, order, 1)
    top /= top.sum(1, keepdims=True)
    joints[:, :k] = cands[order]
    weights[:, :k] = top
    joints[weights == 0.0] = 0
    return joints, weights


def to_float32_normalized(weights: np.ndarray) -> np.ndarray:
    """Float32 weights whose float32 sum is as close to 1 as rounding allows: the
    residual goes to the largest weight, which the validator's sum check needs."""
    w = weights.astype(np.float32)
    resid = np.float32(1.0) - w.sum(1, dtype=np.float32)
    w[:, 0] += resid
    return w
