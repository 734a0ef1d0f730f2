"""The Bayes floor of normal estimation on the CAD validation shapes: the least MSAE that any estimator can reach.

Why: a ratio to PCA says how much better a method is, not how much better it could be. An estimator that knew the
exact clean surface would still see only the noisy position q = p + e of the query point (e ~ N(0, σ²I), p uniform
over the surface by area, as the generator draws it). Near an edge q may lie nearer the wrong face, so even then the
best answer blends the faces' normals by their likelihood. That least expected loss, the Bayes risk, is the floor.

How, exactly for the triangle mesh that the generator samples (no Monte Carlo):

* Posterior over the clean point's triangle t: ∫_t N(q | s, σ²I) ds ∝ exp(-d⊥² / 2σ²) × the in-plane Gaussian mass
  of the triangle around q's projection. That mass is closed-form: the sum, over the triangle's edges, of signed
  right-triangle sectors, each atan(s/h)/2π - T(h, s/h) with Owen's T function (`triangle_mass`). Coplanar
  triangles are pooled into faces (`PlanarSurface`).
* Estimator: the unit normal n minimising the posterior expected sign-invariant squared angle
  Σ_f w_f arccos(|n · n_f|)² (the MSAE of `metrics.py`). It is a weighted Karcher mean on the sphere, found by
  fixed-point steps (n ← exp_n of the weighted mean of the log maps) from two starts, the heaviest face's normal and
  the principal axis of the weighted normals; the better end wins. With two faces one step lands on the
  great-circle arc between them at the weighted position, the exact optimum; on the validation shapes a brute-force
  search over 100,000 directions found nothing better.
* Floor of a cloud: the mean, over eval's query points, of the squared angle between that estimate and the true
  normal: scored exactly as every method is, at the same points.

Only CAD shapes: their faces are planes, so the posterior is exact. On a smooth surface the floor comes from the
normal's variation across the σ-wide posterior patch, about (σ / curvature radius)² (docs/RESULTS.md says why it is
not reported there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

#: Faces whose plane is farther than this many σ from a query get no weight: exp(-32) ≈ 1e-14 of a face at 0.
CUTOFF_SIGMAS = 8.0
#: Coplanar triangles share a face when their unit normals and plane offsets agree to this (cloud units).
PLANE_TOLERANCE = 1e-7
#: Fixed-point steps of the Karcher mean; two faces need one, the round parts' many near-parallel facets a few.
DESCENT_STEPS = 30
#: Posterior weights below this are dropped before the estimate: they move its expected loss by < 1e-11 rad².
NEGLIGIBLE = 1e-12
#: Queries per chunk: bounds the (queries × triangles) arrays to a few tens of MB.
CHUNK = 512


@dataclass(frozen=True)
class PlanarSurface:
    """A closed triangle mesh with its triangles pooled into planar faces: the candidates of the posterior."""

    triangles: np.ndarray  # (T, 3, 3) float64, counter-clockwise about the outward normal
    face_of: np.ndarray  # (T,) int: index into `normals`
    normals: np.ndarray  # (F, 3) unit outward normal of each face

    @classmethod
    def from_mesh(cls, mesh: trimesh.Trimesh) -> PlanarSurface:
        """Pool coplanar triangles (same unit normal and plane offset) into faces; degenerate triangles are dropped."""
        triangles = np.asarray(mesh.triangles, dtype=np.float64)
        cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        area2 = np.linalg.norm(cross, axis=1)
        keep = area2 > 1e-14 * max(float(area2.max(initial=0.0)), 1e-300)
        triangles, normals = triangles[keep], cross[keep] / area2[keep, None]
        offsets = np.einsum("ij,ij->i", normals, triangles[:, 0])
        keys = np.round(np.column_stack([normals, offsets]) / PLANE_TOLERANCE).astype(np.int64)
        _, first, face_of = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        return cls(triangles, face_of.reshape(-1), normals[first])


def validation_surface(name: str, n_points: int, seed: int) -> tuple[PlanarSurface, float]:
    """The clean surface of a CAD validation shape in its cloud's frame, and that cloud's clean bbox diagonal.

    `build_dataset("val", n_points, seed)` normalises each shape by the bbox of its clean sample, not of its mesh, so
    the sample is redrawn here from the same seed (milliseconds) to recover that exact transform; the noise sigma of
    a level is that level × the diagonal of the float32 clean points, as `add_noise` computes it.
    """
    from ..simulation.seeds import derive_seed
    from ..training.dataset import normalise, sample_surface
    from ..training.shapes import catalogue

    spec = next((s for s in catalogue("val") if s.name == name), None)
    if spec is None or spec.kind != "cad":
        raise ValueError(f"{name!r} is not a CAD validation shape")
    raw, _ = sample_surface(spec, n_points, np.random.default_rng(derive_seed(seed, name, "sample")))
    clean, centre, diagonal = normalise(raw)
    clean = clean.astype(np.float32).astype(np.float64)
    mesh = spec.mesh()
    frame = trimesh.Trimesh((np.asarray(mesh.vertices) - centre) / diagonal, mesh.faces, process=False)
    return PlanarSurface.from_mesh(frame), float(np.linalg.norm(clean.max(axis=0) - clean.min(axis=0)))


# ---------------------------------------------------------------- posterior


def triangle_mass(corners: np.ndarray) -> np.ndarray:
    """Mass of the standard 2-D Gaussian N(0, I) over each triangle; `corners` (M, 3, 2), counter-clockwise.

    The triangle is the signed sum of the triangles (0, P, Q) over its edges P → Q; each of those is the difference
    of two right triangles from the foot of the perpendicular, whose mass atan(s/h)/2π - T(h, s/h) follows from
    integrating in polar coordinates (Owen's T function). Exact to rounding: about 1e-16 absolute.
    """
    from scipy.special import owens_t

    p = corners
    q = np.roll(corners, -1, axis=1)
    edge = q - p
    length = np.linalg.norm(edge, axis=2)
    t = edge / np.maximum(length, 1e-300)[..., None]
    h = p[..., 0] * t[..., 1] - p[..., 1] * t[..., 0]  # signed distance from the origin to the edge's line
    s_p, s_q = np.einsum("mek,mek->me", p, t), np.einsum("mek,mek->me", q, t)
    habs = np.maximum(np.abs(h), 1e-300)

    def right(s: np.ndarray) -> np.ndarray:
        return np.arctan2(s, habs) / (2 * np.pi) - owens_t(habs, s / habs)

    sector = np.sign(h) * (right(s_q) - right(s_p))
    sector = np.where((np.abs(h) > 1e-12) & (length > 0), sector, 0.0)
    return np.maximum(sector.sum(axis=1), 0.0)


def face_posterior(surface: PlanarSurface, queries: np.ndarray, sigma: float) -> np.ndarray:
    """(Q, F) posterior probability that the clean point of each noisy query lies on each face (rows sum to 1)."""
    tri = surface.triangles
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    e1 = tri[:, 1] - tri[:, 0]
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normals, e1)
    rel = tri - tri[:, :1]
    flat = np.stack([np.einsum("tvk,tk->tv", rel, e1), np.einsum("tvk,tk->tv", rel, e2)], axis=2)  # (T, 3, 2)
    middle = tri.mean(axis=1)  # a ball around each triangle: queries beyond it by the cutoff get no weight from it
    radius = np.linalg.norm(tri - middle[:, None], axis=2).max(axis=1)

    out = np.zeros((len(queries), len(surface.normals)))
    for start in range(0, len(queries), CHUNK):
        q = np.asarray(queries[start : start + CHUNK], dtype=np.float64)
        offset = q[:, None, :] - tri[None, :, 0]  # (Q, T, 3)
        dist = np.einsum("qtk,tk->qt", offset, normals) / sigma
        reach = np.linalg.norm(q[:, None, :] - middle[None], axis=2) < radius + CUTOFF_SIGMAS * sigma
        qi, ti = np.nonzero((np.abs(dist) < CUTOFF_SIGMAS) & reach)
        pair = offset[qi, ti]
        centre = np.stack([np.einsum("mk,mk->m", pair, e1[ti]), np.einsum("mk,mk->m", pair, e2[ti])], axis=1)
        mass = triangle_mass((flat[ti] - centre[:, None, :]) / sigma)
        weight = np.exp(-0.5 * dist[qi, ti] ** 2) * mass
        np.add.at(out, (start + qi, surface.face_of[ti]), weight)
    total = out.sum(axis=1, keepdims=True)
    lost = total[:, 0] <= 0  # farther than CUTOFF_SIGMAS from every face (p ≈ 1e-13 per query): the nearest plane
    if lost.any():
        out[lost] = _nearest_plane(surface, queries[lost])
        total[lost] = 1.0
    return out / total


def _nearest_plane(surface: PlanarSurface, queries: np.ndarray) -> np.ndarray:
    """One-hot rows on the face whose plane is nearest: a fallback that the cutoff makes practically unreachable."""
    tri = surface.triangles
    offsets = np.einsum("tk,tk->t", surface.normals[surface.face_of], tri[:, 0])
    dist = np.abs(np.asarray(queries, dtype=np.float64) @ surface.normals[surface.face_of].T - offsets)
    rows = np.zeros((len(queries), len(surface.normals)))
    rows[np.arange(len(queries)), surface.face_of[dist.argmin(axis=1)]] = 1.0
    return rows


# ---------------------------------------------------------------- estimator


def expected_loss(n: np.ndarray, weights: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Σ_f w_f arccos(|n · n_f|)² per row: the posterior expected sign-invariant squared angle of estimate n (Q, 3),
    for weights (Q, K) on per-row candidate normals (Q, K, 3)."""
    cos = np.clip(np.abs(np.einsum("qk,qfk->qf", n, normals)), 0.0, 1.0)
    return np.sum(weights * np.arccos(cos) ** 2, axis=1)


def _karcher(n: np.ndarray, weights: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Fixed-point steps n ← exp_n(Σ w_f log_n(±n_f)), the sign of each n_f taken towards n (sign invariance)."""
    for _ in range(DESCENT_STEPS):
        dot = np.einsum("qk,qfk->qf", n, normals)
        cos = np.clip(np.abs(dot), 0.0, 1.0)
        angle = np.arccos(cos)
        scale = weights * np.where(angle > 1e-12, angle / np.maximum(np.sin(angle), 1e-300), 1.0)
        toward = np.einsum("qf,qfk->qk", scale * np.where(dot < 0, -1.0, 1.0), normals)
        step = toward - np.sum(scale * cos, axis=1, keepdims=True) * n
        size = np.linalg.norm(step, axis=1, keepdims=True)
        n = np.cos(size) * n + np.sin(size) * step / np.maximum(size, 1e-300)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    return n


def bayes_normals(weights: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The posterior-optimal unit normals (Q, 3) and their expected squared angles (Q,), for (Q, F) posterior weights
    on shared candidate normals (F, 3) (the faces) or on per-query ones (Q, F, 3) (e.g. a dense surface sample's).
    Only weights above NEGLIGIBLE take part: the rest move the loss by less than 1e-11."""
    keep = max(int((weights > NEGLIGIBLE).sum(axis=1).max(initial=1)), 1)
    order = np.argsort(-weights, axis=1)[:, :keep]
    w = np.take_along_axis(weights, order, axis=1)
    w = np.where(w > NEGLIGIBLE, w, 0.0)
    shared = normals.ndim == 2
    candidates = normals[order] if shared else np.take_along_axis(normals, order[..., None], axis=1)  # heaviest first
    principal = np.linalg.eigh(np.einsum("qf,qfi,qfj->qij", w, candidates, candidates))[1][:, :, -1]
    ends = [_karcher(start, w, candidates) for start in (candidates[:, 0], principal)]
    losses = np.stack([expected_loss(n, w, candidates) for n in ends])
    best = losses.argmin(axis=0)
    return np.where(best[:, None] == 0, ends[0], ends[1]), losses.min(axis=0)


def floor_angles(
    surface: PlanarSurface, queries: np.ndarray, sigma: float, truth: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per query: the squared angle (rad²) of the Bayes estimate to the true normal, and its posterior expectation.

    Their means estimate the same floor; a large gap between them would mean the posterior is wrong.
    """
    from .metrics import angles_rad

    if sigma <= 0:
        zeros = np.zeros(len(queries))
        return zeros, zeros
    weights = face_posterior(surface, queries, sigma)
    estimate, expected = bayes_normals(weights, surface.normals)
    return angles_rad(estimate, truth) ** 2, expected
