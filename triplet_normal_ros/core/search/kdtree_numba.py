"""A compiled KD-tree for the pool path on a CPU: the nearest k points strictly inside a ball, sorted by distance.

scipy's cKDTree answered these searches before; on a 640 × 480 depth frame at k = 30 its query alone took longer than
Open3D's whole normal estimate (docs/HISTORY.md, "A compiled KD-tree"). This tree is a nanoflann-class search in numba:

* **Layout.** A balanced tree of fixed depth, its nodes in heap order (children 2i + 1, 2i + 2), each split at the
  median of its widest axis, every leaf holding LEAF_SIZE / 2 to LEAF_SIZE points (a cloud of fewer is one leaf).
  The points are copied in leaf order, once as rows and once as three coordinate columns, so a leaf's points are
  contiguous in memory and its distances are one vector loop over the columns; every node keeps its points'
  bounding box: a node is skipped when its box lies farther than the current k-th distance, which prunes tighter
  than the split plane alone.
* **Query.** Depth first, nearer child first, one small stack per query. A centre that is one of the tree's own
  points (every pool search of a cloud) starts at its own leaf and climbs, searching each ancestor's other child,
  which saves the descent from the root; any other centre descends from the root. A leaf is scanned in two passes:
  the distances of all its points, then the candidates among them. The best k are kept as a sorted list: a
  candidate is inserted by shifting the farther ones up. The leaves come nearest first, so most insertions shift
  little, and the list needs no final sort; at k = 30 to 512 this measured as fast as a heap or faster.
* **Ties.** Equal distances order by the point's id, so an answer is one exact set whatever the traversal.

Queries run in bands on `bands.bands`'s threads (torch's thread count, the GIL released), for the reasons bands.py
gives. test/core/test_kdtree.py checks the answers against scipy's cKDTree, and the speed is in RESULTS.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..bands import bands

#: Points per leaf at most (half of it at least). 24 and 32 measured fastest at k = 30 on a depth frame with the
#: two-pass leaf scan (16: 6 % slower, 8: 18 %).
LEAF_SIZE = 24
#: Levels split before the subtrees below them split in parallel (8 subtrees: 4 per thread on 2): the root on one
#: thread, the levels below it in its two halves at once.
TOP_LEVELS = 3
#: The query's stack bound: the stack holds at most one node per level below the one being visited, and no tree of
#: this layout is 64 levels deep.
_STACK = 64


class Scratch(NamedTuple):
    """One query thread's working arrays."""

    best: np.ndarray  # (k + 1,) squared distances of the best so far, nearest first
    best_pos: np.ndarray  # (k + 1,) their places in the tree's points
    stack: np.ndarray  # nodes still to visit
    stack_bound: np.ndarray  # their boxes' squared distances
    last: np.ndarray  # the previous centre and its k-th distance (-1: none)
    leaf_distance: np.ndarray  # (the tree's largest leaf,) the squared distances of the leaf being scanned


@njit(cache=True, nogil=True)
def scratch_for(k, leaf_size):
    """A `Scratch` for searches of k points in a tree whose largest leaf holds `leaf_size` points (`KDTree.leaf_size`:
    the tree's own figure, so compiled code cached before a change of LEAF_SIZE still sizes its buffer right)."""
    return Scratch(np.empty(k + 1), np.empty(k + 1, dtype=np.int64), np.empty(_STACK, dtype=np.int64),
                   np.empty(_STACK), np.array([0.0, 0.0, 0.0, -1.0]), np.empty(max(leaf_size, 1)))  # fmt: skip


class KDTree:
    """A KD-tree over finite points (N, 3); `nearest` answers with `ids` (default: the rows of `points`)."""

    def __init__(self, points: np.ndarray, ids: np.ndarray | None = None) -> None:
        points = np.ascontiguousarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            raise ValueError(f"a KD-tree needs finite points of shape (N, 3), got {points.shape}")
        n = len(points)
        ids = np.arange(n, dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64)
        self.size = n
        self.depth = (-(-n // LEAF_SIZE) - 1).bit_length() if n else 0  # the fewest levels with leaves of <= LEAF_SIZE
        self.points, order, self.span, self.box = _build(points, self.depth)
        first = (1 << self.depth) - 1
        self.leaf_size = int((self.span[first:, 1] - self.span[first:, 0]).max())
        self.columns = np.ascontiguousarray(self.points.T)  # (3, N): the leaf scan's vector loop reads these
        self.leaf = _leaf_of(self.span, self.depth)
        self.ids = ids[order]
        self.position = np.empty(n, dtype=np.int64)  # each row of `points`' place in leaf order
        self.position[order] = np.arange(n)

    def nearest(self, centres: np.ndarray, radius: float, k: int, rows: np.ndarray | None = None) -> np.ndarray:
        """(M, k) int64: the ids of the nearest `k` points at a distance strictly under `radius` from each centre,
        nearest first (equal distances by id), -1 padded; a non-finite centre gets none.

        Where the centres are the tree's own points, `rows` (M,) names them (rows of the points it was built on, -1
        for none) and the queries run in leaf order (`in_leaf_order`)."""
        out = np.full((len(centres), k), -1, dtype=np.int64)
        if self.size and len(centres) and k > 0:
            centres, at, which, starts = self.in_leaf_order(centres, rows)
            bands(
                _query, len(at), self.columns, self.ids, self.span, self.box, self.depth, self.leaf_size, centres, at,
                which, starts, float(radius) ** 2, out, pieces=4,
            )  # fmt: skip
        return out

    def in_leaf_order(
        self, centres: np.ndarray, rows: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(coordinates, at, which, starts): the j-th query is the centre at coordinates[at[j]], answers row which[j]
        and starts its search at the leaf node starts[j] (-1: at the root).

        With `rows` (see `nearest`) the queries follow the leaves, read the tree's own copy of each centre and start
        from the leaf that holds it: consecutive queries then share their nodes in cache and their bounds (`_query`),
        1.1-1.3 × faster than a depth image's raster order and 2 × faster than a shuffled cloud's (k = 30, 300k
        points)."""
        if rows is None:
            centres = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
            which = np.arange(len(centres))
            return centres, which, which, np.full(len(centres), -1, dtype=np.int64)
        rows = np.asarray(rows, dtype=np.int64)
        which = self._leaf_order(rows)
        if (rows >= 0).all():
            at = self.position[rows[which]]
            return self.points, at, which, self.leaf[at]
        centres = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
        own = rows[which] >= 0
        at = np.where(own, self.position[rows[which]], self.size + which)
        starts = np.where(own, self.leaf[np.minimum(at, self.size - 1)], -1)
        return np.concatenate((self.points, centres)), at, which, starts

    def _leaf_order(self, rows: np.ndarray) -> np.ndarray:
        """The order of `rows` (the tree's own rows, -1 for none) that follows their places in leaf order, the
        others after them as given: a stable argsort of the places. Each key also carries its index, so no two keys
        tie and numpy's default sort, about twice as fast as its stable one on a chunk of 65k rows, gives the
        stable order."""
        places = np.where(rows >= 0, self.position[rows], self.size)
        return np.argsort(places * len(rows) + np.arange(len(rows)))


def warm() -> None:
    """Compile (or load from the cache) the build and the query on a tiny cloud: the node's start-up probe calls
    this, so that no cloud waits for it."""
    cloud = np.random.default_rng(0).random((40, 3))
    KDTree(cloud).nearest(cloud[:4], 0.5, 8)


def _leaf_of(span: np.ndarray, depth: int) -> np.ndarray:
    """(N,) int64: the leaf node that holds each place in leaf order."""
    first = (1 << depth) - 1
    leaves = span[first:]
    return np.repeat(np.arange(first, first + len(leaves)), leaves[:, 1] - leaves[:, 0])


def _build(points: np.ndarray, depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tree of `depth` levels over `points`: (points in leaf order, their rows in `points`, each node's
    [start, end) in that order (nodes, 2), each node's box (nodes, 6): min x y z, max x y z). The root splits on one
    thread, the rest of the first TOP_LEVELS levels in the root's two halves at once, and the subtrees below them on
    `bands.bands`' threads."""
    n, nodes = len(points), (1 << (depth + 1)) - 1
    pts, order = points.copy(), np.arange(n)
    span, box = np.empty((nodes, 2), dtype=np.int64), np.empty((nodes, 6))
    span[0] = 0, n
    top = min(TOP_LEVELS, depth)
    first = min(1, top)
    _split_levels(pts, order, span, box, 0, first, depth, 0, 1)
    bands(_split_levels, 1 << first, pts, order, span, box, first, top, depth, pieces=4)
    bands(_split_levels, 1 << top, pts, order, span, box, top, depth + 1, depth, pieces=4)
    return pts, order, span, box


@njit(cache=True, nogil=True, error_model="numpy")
def _split_levels(pts, order, span, box, first, stop, depth, lo, hi):
    """Box the nodes of levels [first, stop) below the level-`first` nodes lo..hi - 1 (counted along the level), and
    split each one above the leaves (level `depth`) at the median of its widest axis. Bands of level-`first` nodes own
    disjoint subtrees, point ranges and node rows, so threads can split them at once."""
    for level in range(first, stop):
        scale = 1 << (level - first)
        for place in range(lo * scale, hi * scale):
            node = (1 << level) - 1 + place
            start, end = span[node, 0], span[node, 1]
            _bounds(pts, start, end, box, node)
            if level == depth:
                continue
            axis = 0
            for a in range(1, 3):
                if box[node, 3 + a] - box[node, a] > box[node, 3 + axis] - box[node, axis]:
                    axis = a
            mid = start + (end - start) // 2
            _select(pts, order, start, end, mid, axis)
            span[2 * node + 1, 0], span[2 * node + 1, 1] = start, mid
            span[2 * node + 2, 0], span[2 * node + 2, 1] = mid, end


@njit(cache=True, nogil=True, inline="always")
def _bounds(pts, lo, hi, box, node):
    """The box of pts[lo:hi] into box[node]; the running bounds stay in locals (registers) and are stored once."""
    x0 = y0 = z0 = np.inf
    x1 = y1 = z1 = -np.inf
    for t in range(lo, hi):
        x, y, z = pts[t, 0], pts[t, 1], pts[t, 2]
        x0, x1 = min(x0, x), max(x1, x)
        y0, y1 = min(y0, y), max(y1, y)
        z0, z1 = min(z0, z), max(z1, z)
    box[node, 0], box[node, 1], box[node, 2] = x0, y0, z0
    box[node, 3], box[node, 4], box[node, 5] = x1, y1, z1


@njit(cache=True, nogil=True)
def _select(pts, order, lo, hi, nth, axis):
    """Reorder pts[lo:hi] (and `order` with them) so that the point at `nth` is the one a sort along `axis` would put
    there, smaller or equal before it and greater or equal after (Hoare's quickselect, median-of-three pivot)."""
    while hi - lo > 1:
        mid = (lo + hi - 1) // 2
        a, b, c = pts[lo, axis], pts[mid, axis], pts[hi - 1, axis]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = lo, hi - 1
        while i <= j:
            while pts[i, axis] < pivot:
                i += 1
            while pts[j, axis] > pivot:
                j -= 1
            if i <= j:
                for d in range(3):
                    pts[i, d], pts[j, d] = pts[j, d], pts[i, d]
                order[i], order[j] = order[j], order[i]
                i += 1
                j -= 1
        if nth <= j:
            hi = j + 1
        elif nth >= i:
            lo = i
        else:
            return


@njit(cache=True, nogil=True, inline="always")
def _gap(low, high, v):
    """Squared distance from v to the interval [low, high] (without branches: a mispredicted one costs more)."""
    g = max(low - v, v - high, 0.0)
    return g * g


@njit(cache=True, nogil=True, inline="always")
def _box_distance(box, node, x, y, z):
    """Squared distance from (x, y, z) to the node's box (0 inside it)."""
    gaps = _gap(box[node, 0], box[node, 3], x) + _gap(box[node, 1], box[node, 4], y)
    return gaps + _gap(box[node, 2], box[node, 5], z)


@njit(cache=True, nogil=True, error_model="numpy")
def _query(cols, ids, span, box, depth, leaf_size, centres, at, which, starts, r2, out, lo, hi):
    """The sorted nearest out.shape[1] ids strictly inside squared radius `r2` of centres[at[lo:hi]], into the rows
    which[lo:hi] of `out` (pre-filled with -1), each search from the leaf in starts[lo:hi] (-1: the root)."""
    k = out.shape[1]
    scratch = scratch_for(k, leaf_size)
    for j in range(lo, hi):
        c = at[j]
        x, y, z = centres[c, 0], centres[c, 1], centres[c, 2]
        count = _nearest_one(cols, ids, span, box, depth, starts[j], x, y, z, r2, k, scratch)
        for a in range(count):
            out[which[j], a] = ids[scratch.best_pos[a]]


@njit(cache=True, nogil=True, inline="always")
def _nearest_one(cols, ids, span, box, depth, own, x, y, z, r2, k, scratch):
    """The nearest k points to (x, y, z) under squared radius r2 into scratch.best (squared distances) and
    scratch.best_pos (places in the tree), nearest first; returns how many (0 for a non-finite centre). `own`: a leaf
    node to start from, the one that holds the centre when it is one of the tree's points (any leaf gives the same
    answer, since the climb visits the whole tree; the nearest leaf gives it fastest), else -1: from the root.

    Consecutive centres are usually close, so the previous centre's k-th distance plus the step between them bounds
    this one's from the start (its k points lie within that reach), and the search prunes at once instead of after k
    points were found inside the ball; a bound that rounding made too tight is searched again with the ball's."""
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return 0
    last = scratch.last
    bound = r2
    if last[3] >= 0.0:
        seeded = last[3] + math.sqrt((x - last[0]) ** 2 + (y - last[1]) ** 2 + (z - last[2]) ** 2)
        bound = min(r2, seeded * seeded * (1.0 + 1e-9))
    count = _search(cols, ids, span, box, depth, own, x, y, z, r2, bound, k, scratch)
    if count < k and bound < r2:
        count = _search(cols, ids, span, box, depth, own, x, y, z, r2, r2, k, scratch)
    last[0], last[1], last[2] = x, y, z
    last[3] = math.sqrt(scratch.best[k - 1]) if count == k else -1.0
    return count


@njit(cache=True, nogil=True, inline="always")
def _search(cols, ids, span, box, depth, own, x, y, z, r2, bound, k, scratch):
    """The nearest k points to (x, y, z) at squared distances under r2 and at most `bound` into scratch.best (squared
    distances) and scratch.best_pos, nearest first (equal distances by id); returns how many were found. From the
    root, or with `own` from that leaf up: its points, then each ancestor's other child, nearest levels first."""
    if own < 0:
        return _subtree(cols, ids, span, box, depth, 0, _box_distance(box, 0, x, y, z), x, y, z, r2, k, scratch, 0,
                        bound)[0]  # fmt: skip
    count, worst = _scan(cols, ids, span[own, 0], span[own, 1], x, y, z, r2, k, scratch, 0, bound)
    node = own
    while node > 0:
        other = node + 1 if node & 1 else node - 1
        reach = _box_distance(box, other, x, y, z)
        node = (node - 1) >> 1
        if reach <= worst and reach < r2:
            count, worst = _subtree(cols, ids, span, box, depth, other, reach, x, y, z, r2, k, scratch, count, worst)
    return count


@njit(cache=True, nogil=True, inline="always")
def _subtree(cols, ids, span, box, depth, root, reach, x, y, z, r2, k, scratch, count, worst):
    """The search below node `root` (its box at squared distance `reach`), nearer child first, adding to the `count`
    best found so far; `worst` is their k-th distance once k are found, until then the bound. Returns both."""
    stack, stack_bound, first_leaf = scratch.stack, scratch.stack_bound, (1 << depth) - 1
    stack[0], stack_bound[0], top = root, reach, 1
    while top > 0:
        top -= 1
        node = stack[top]
        if stack_bound[top] > worst or stack_bound[top] >= r2:
            continue
        while node < first_leaf:
            near, far = 2 * node + 1, 2 * node + 2
            d_near, d_far = _box_distance(box, near, x, y, z), _box_distance(box, far, x, y, z)
            if d_far < d_near:
                near, far, d_near, d_far = far, near, d_far, d_near
            if d_far <= worst and d_far < r2:
                stack[top], stack_bound[top] = far, d_far
                top += 1
            node = near if d_near <= worst and d_near < r2 else -1
            if node < 0:
                break
        if node >= 0:
            count, worst = _scan(cols, ids, span[node, 0], span[node, 1], x, y, z, r2, k, scratch, count, worst)
    return count, worst


@njit(cache=True, nogil=True, inline="always")
def _scan(cols, ids, lo, hi, x, y, z, r2, k, scratch, count, worst):
    """Add the leaf cols[:, lo:hi] to the `count` best so far (see `_subtree`); returns (count, worst). The distances
    come first in one loop the compiler vectorises; the insertions, which branch, only visit those under the bound."""
    best, best_pos, dist = scratch.best, scratch.best_pos, scratch.leaf_distance
    xs, ys, zs = cols[0], cols[1], cols[2]
    for i in range(hi - lo):
        dx, dy, dz = xs[lo + i] - x, ys[lo + i] - y, zs[lo + i] - z
        dist[i] = dx * dx + dy * dy + dz * dz
    for i in range(hi - lo):
        d, t = dist[i], lo + i
        if d >= r2 or d > worst:
            continue
        if count == k and d == worst and ids[t] > ids[best_pos[k - 1]]:
            continue
        c = count
        while c > 0 and (best[c - 1] > d or (best[c - 1] == d and ids[best_pos[c - 1]] > ids[t])):
            best[c], best_pos[c] = best[c - 1], best_pos[c - 1]
            c -= 1
        best[c], best_pos[c] = d, t
        if count < k:
            count += 1
        if count == k:
            worst = best[k - 1]
    return count, worst
