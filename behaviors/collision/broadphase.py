"""Collision broad phase: a linear BVH over swept, inflated primitive boxes, and a uniform hash grid.

Everything here works on plain float64/int64 arrays that the caller owns; there is no hidden
global state. The hot paths are numba kernels (``@njit(cache=True)``, ``parallel=True`` where a
loop over primitives is independent); Python only loops over passes, never over primitives or pairs.

Conventions
-----------
* Positions ``X0``, ``X1``: vertex positions [m] at the start and the end of a (sub)step,
  shape ``(vertex_count, 3)``, float64. A primitive moves linearly from ``X0`` to ``X1``.
* Primitives: an int array ``prims`` of shape ``(m, k)`` of vertex indices, ``k = 1`` (points),
  ``2`` (edges) or ``3`` (triangles). A 1-D array of vertex indices is taken as points.
* Thickness [m]: a scalar, or a per-vertex array of shape ``(vertex_count,)``. A primitive's box
  is inflated by the largest thickness over its vertices. Two inflated boxes overlap when the
  primitives come within ``thickness_a + thickness_b`` of each other (per axis), so to find
  every pair closer than a contact distance ``d`` inflate both sets by ``d / 2`` (or one by
  ``d`` and the other by 0). Inflated bounds are rounded outward, so the stored box contains
  the exact inflated box.
* Boxes: ``lo``, ``hi`` of shape ``(m, 3)``. Box overlap is closed: boxes that only touch overlap.
* Candidate pairs: an int64 array of shape ``(pair_count, 2)``. The order of the rows is
  deterministic (independent of the thread count) but otherwise unspecified.

BVH
---
:func:`build_bvh` builds a *linear BVH* (Karras 2012): 63-bit Morton codes (21 bits per axis) of the
box centres in the box of all centres, a stable sort, then every internal node found
independently (in parallel) from the longest common prefix of neighbouring codes, ties broken by
leaf position. That gives ``n - 1`` binary internal nodes over ``n`` leaves. Node layout, in one
index space of ``2 n - 1`` nodes: internal nodes ``0 .. n-2`` (node 0 is the root), leaf ``k``
(the ``k``-th primitive in Morton order) is node ``n - 1 + k``; with ``n == 1`` the root is the
single leaf 0. :func:`refit_bvh` recomputes the boxes in place without changing the topology:
the tree is cut into at least 64 subtrees that are refit bottom-up in parallel (one task each,
one parallel region), then the few nodes above the cut serially (trees under 8,192 internal
nodes are refit serially). Quality is measured by the normalised SAH cost :func:`bvh_cost` =
(sum of the surface areas of the internal nodes) / (surface area of the root);
:func:`needs_rebuild` says when it has grown by more than a factor over its value at build.

Queries (candidate pairs whose boxes overlap)
---------------------------------------------
* :func:`query_self` -- one primitive set against itself (edge-edge, triangle-triangle), each
  unordered pair once as ``(i, j)`` with ``i < j``, pairs sharing a vertex skipped.
* :func:`query_self_ee` -- :func:`query_self` over a mesh's edges.
* :func:`query_self_vf` -- vertices against triangles of the same mesh, rows ``(vertex, face)``,
  skipping a vertex against its own triangles.
* :func:`query_pairs` -- the leaves of BVH ``a`` against those of BVH ``b``, rows ``(prim_a, prim_b)``;
  with ``prims_a``/``prims_b`` given (same vertex numbering), pairs sharing a vertex are skipped.
* :func:`query_boxes` -- arbitrary boxes against a BVH, rows ``(box, prim)``.

:func:`query_self` and :func:`query_pairs` traverse both trees simultaneously (one tree against
itself for self queries): only overlapping node pairs are expanded, the node with the larger box
is split first, and a self task ``(u, u)`` spawns ``(l, l)``, ``(r, r)`` and, if their boxes
overlap, ``(l, r)``, so each unordered leaf pair is met exactly once. Two subtrees of at most 8
leaves each (their leaves are contiguous in Morton order) are compared leaf by leaf instead of
being descended further, which halves the node visits near the bottom. The top of that recursion is
expanded serially into about 1,024 independent node-pair tasks, which are run in parallel (in a
fixed shuffled order, for load balance across threads). The number of tasks does not depend on
the thread count, so the output order is the same on every machine. :func:`query_boxes`
traverses the tree once per query box.

Space-time boxes (:func:`spacetime_boxes`, the ``st`` arguments of the tree-tree queries): the
box of a primitive at the start and the box of its vertices' displacements. A common
translation cancels in them, so pairs whose swept boxes overlap only because both move the
same way (a falling sheet and its neighbours) are dropped: a cluster pair (two subtrees of at
most 8 leaves, see above) or a leaf pair is kept only if, on every axis, the gap between the
start boxes can be closed by the relative displacement. Pairs of two *inactive* primitives
(e.g. of kinematic objects) are never reported, and pairs of different *groups* are kept by
their swept boxes alone. Measured on a frame-12 detection of ``cloth_sphere_64`` (cloth
draping on the sphere, 1 thread): edge-edge candidates 281,881 -> 98,459 (cloth-cloth
207,324 -> about 24,000), vertex-face 105,929 -> 29,105, for about the same traversal time
(the leaf tests, not the output, dominate it: 100k node pairs and 430k-700k leaf tests).

Without a :class:`PairBuffer` a query runs two passes (count, then fill at prefix-sum offsets),
so the output is allocated once at its exact size. With one that has seen a tree-tree query
before, the traversal runs once: the tasks (in their shuffled order) are cut into equal runs (2
per thread, at most 32), each writing its tasks' pairs one after another into its slot of a
scratch array kept in the buffer and sized from the buffer's previous pair count (2x: measured
on cloth_sphere_64 at 1 thread, 32 runs of 1.25x made about 70 of the 106 queries of 10 frames
traverse overflowing tasks again, a tenth of the traversal time; 2 runs of 2x, none); the
pairs are then gathered to their prefix-sum offsets, and only tasks that did not fit are
traversed again. The rows and their order are exactly those of the two-pass query. No
per-pair Python work.

Sorted column grid
------------------
:func:`column_query_self` and :func:`column_query_pairs` return exactly the candidate pairs of
:func:`query_self` and :func:`query_pairs` (same boxes, same space-time, inactive-primitive and
shared-vertex tests on the primitives; ``st`` are the primitives' own rows,
:func:`spacetime_prim_boxes`) without building a tree: sweep and prune in the columns of a
uniform 2-D grid. The sweep axis is the one along which the box centres spread most; the other
two are cut into square columns of side ``COLUMN_CELL`` x the mean box extent across them (the
side doubles while there would be more than 8 n + 1024 columns or more than n / 256 + 32 big
boxes). Every box is entered into each column it crosses; a counting sort of the boxes taken in
order of their low end on the sweep axis lists every column sorted (in pair mode the set-a
entries first, then the set-b ones). Each column is swept: an entry against the following ones
while their low end is within its high end (pair mode: set a against set b and back, each pair
once), the two column axes compared, and a pair is kept only in the column holding the low
corner of its overlap on the column axes (one of its two entries is its box's first column on
each axis), so every pair is found exactly once. Boxes crossing more than ``_COL_BIG_SPAN``
columns on an axis (e.g. a large collider triangle) are tested against every box instead. The
rows come column by column (in pair mode a column's a-b pairs from its a entries, then from its
b entries): deterministic and independent of the thread count, but in another order than the
trees'. Columns are swept in parallel in runs of about equal entry counts (eight per thread,
dealt one at a time); with
a :class:`PairBuffer` that has seen a query the sweep runs once, into scratch sized from its
previous pair count (a run that overflows is swept again), else a count pass comes first.
Measured on the rolled sheet of ``python -m lokigraph.bench.broadphase`` at 50k triangles
(1 thread, CPU time, interleaved): vertex-face plus edge-edge 30 ms for boxes+query against
98 ms for the BVH's refit+query (0.30x). Inside the collision contacts on the 64 x 64 drop
(frames 6-10, 1 thread, both run on the same detections): the self queries with the
primitives' space-time rows took 622 ms against 1,081 ms for the trees' builds, space-time
boxes and queries.

The setup (sweep axis, column side, big boxes, finiteness) runs in a fixed number of chunks of
the boxes in parallel (one pass over the boxes gives the spreads, the mean extents for every
sweep axis and the sort keys' range); the boxes' order along the sweep axis comes from a bucket
sort (buckets of equal width, each sorted on its own: ``np.argsort(kind="stable")``'s order);
every box's columns are packed once into one int64, in the sort's pass that counts its buckets.
The column count and the counting sort run in chunks of the sorted boxes on all threads from
16,384 boxes (``_COL_PAR_MIN``: per-chunk column counts, each chunk filling its own runs), the
same entries in the same order as one pass.

:func:`column_queries` runs several queries (the self vertex-face and edge-edge queries of a
detection) side by side with ``COLUMN_SIDE_BY_SIDE`` (opt-in): each on its own thread with one
numba thread (the column kernels release the GIL), so no barrier joins the threads between the
stages and every sweep writes its rows straight into its output; the same rows in the same order.

Canonical pair order
--------------------
:func:`sort_pairs` (a counting sort by the first index, or by given ranks) and
:func:`zsort_pairs` (an LSD radix sort by the Z-order of the pair's two ranks, with
:func:`morton_rank`: the Morton order of the primitives, the trees' leaf order) put a candidate
set in an order that does not depend on the query that found it: the collision contacts sort
the column grid's candidates by the Z-order (``contacts.GRID_ORDER``), whose spatially
coherent blocks converge about as well in their Gauss-Seidel projection as the trees' order.

Hash grid
---------
:func:`build_hash_grid` bins points into cubic cells of side ``cell_size`` hashed into a table of
``2^p >= 2 * point_count`` buckets (counting sort, CSR layout). :func:`hash_grid_pairs` returns
the point pairs within a radius, :func:`hash_grid_query_boxes` the (box, point) pairs with the
point inside the closed box. Every bucket entry is checked against its exact integer cell, so hash
collisions cost time but never produce duplicates or wrong pairs.

References
----------
T. Karras, "Maximizing parallelism in the construction of BVHs, octrees, and k-d trees",
High-Performance Graphics 2012. M. Teschner et al., "Optimized spatial hashing for collision
detection of deformable objects", VMV 2003.

Limitations
-----------
* The LBVH splits at Morton-code boundaries, not at SAH-optimal planes; on very anisotropic
  scenes its boxes are looser than a binned-SAH build (more traversal work, same candidates).
* Refit keeps the topology: after large deformation the boxes overlap more; call
  :func:`needs_rebuild` and rebuild.
* Queries without a :class:`PairBuffer` (and a buffer's first tree-tree query) traverse twice
  (count pass, fill pass); with a buffer, about once (see above).
* :class:`BVHCache` can keep trees and refit them between detection passes. The collision
  contacts build their trees every pass: a refit tree lists the same pairs in another order,
  which changes the Gauss-Seidel order of the contacts, for about 5 % of the frame time (see
  its docstring).
* Box overlap is a float comparison of the stored boxes; box construction rounds thickness
  inflation outward, zero-thickness boxes are exact min/max of the vertex coordinates.
* Inputs are assumed finite (NaN positions give undefined boxes). The hash grid also assumes
  coordinates / cell_size well inside the int64 range.
"""

from __future__ import annotations

import contextlib
from typing import NamedTuple

import numpy as np
from numba import get_num_threads, njit, parallel_chunksize, prange

__all__ = [
    "BVH",
    "HashGrid",
    "PairBuffer",
    "primitive_boxes",
    "build_bvh",
    "refit_bvh",
    "bvh_cost",
    "needs_rebuild",
    "update_bvh",
    "BVHCache",
    "bvh_cache",
    "query_self",
    "spacetime_boxes",
    "query_self_vf",
    "query_self_ee",
    "query_pairs",
    "query_boxes",
    "build_hash_grid",
    "hash_grid_pairs",
    "hash_grid_query_boxes",
    "mesh_edges",
    "spacetime_prim_boxes",
    "column_query_self",
    "column_query_pairs",
    "column_queries",
    "sort_pairs",
    "zsort_pairs",
    "morton_rank",
]

_NO_LIMIT = 1 << 62  # write limit of a fill pass at exact offsets (never reached)
_CHUNKS = 512  # work items of a parallel query are split into at most this many chunks
_CLUSTER = 8  # node pairs whose leaf ranges both hold at most this many leaves are tested leaf by leaf
_SLOTS = 32  # single-pass traversals write into at most this many scratch runs
#: ... and at most this many per thread: fewer, larger runs overflow less often (a task with
#: more pairs than its run holds is traversed again); the rows do not depend on the run count
_SLOTS_PER_THREAD = 2
_TASKS = 1024  # simultaneous traversals start from at least this many node-pair tasks
_REFIT_MIN_PARALLEL = 8192  # trees with fewer internal nodes are refit serially
_REFIT_SUBTREES = 64  # refit splits the tree into at least this many subtrees (one task each)
_ST_TOL = 1e-9  # [m] slack of the space-time box test over rounding
_NO_ST = np.zeros((0, 14))
#: the size a grow-only buffer (pair buffers, their scratch, the column grid's work arrays, and
#: the contacts' row and pack buffers) takes when ``need`` entries overflow its ``capacity``:
#: ``GROW_HEADROOM`` times what is needed (its untouched tail costs address space only, no
#: pages), so a count that climbs over a few detections (the rows of a landing cloth grow 5-10x
#: within two frames) reallocates, and writes into fresh pages, a few times rather than at
#: every detection. 0: ``max(need, 1.5 capacity)`` as before (at most exactly what is needed
#: when the count jumps by more than half). The buffers' contents and the results are the same
#: either way (positions after 12 frames of cloth_sphere_128 and cloth_sphere_moving_128
#: bitwise equal). Where the time went: the kernel's share of the CPU (page faults, zeroing
#: and compacting fresh huge pages: numpy advises them for large arrays) was 0.6 s (static)
#: and 1.1 s (moving) a frame over frames 8-12 of those scenes, in the first detection's
#: filters, pack, cull, sort and queries, and none once the rows stop growing (frames 11-12).
#: ``peer_collision.py --moving --stages`` reports that share per part as ``y_STAGE.PART``.
#: Measured 0 -> 2 in two interleaved runs, 1 thread, mean of frames 8-12: CPU 4,270 -> 4,158
#: ms a frame (static) and 8,124 -> 7,734 (moving), the kernel's share 638 -> 478 and 1,107 ->
#: 1,013 ms (load ~3); CPU 4,427 -> 4,410 and 8,443 -> 8,449, the first detection's kernel
#: share 580 -> 523 and 1,068 -> 904 ms (load 6: ``NUMBA_NUM_THREADS=1 peer_collision.py
#: --moving --loki 2x15 --stages --stage-frames 8 12 --frames 12 --all-flag
#: broadphase.GROW_HEADROOM=0``): a small gain, within the noise of the frame's CPU.
#: The rest is the resident memory itself growing (1.3 -> 4.2 GB over frames 8-10 of the
#: moving scene: ~220 bytes a row in two alternating pack sets, the pair buffers, the sort
#: keys and the cull's), which no reuse avoids
GROW_HEADROOM = 2.0


def grown_size(need: int, capacity: int) -> int:
    """Entries to allocate for ``need`` entries in a buffer of ``capacity`` (need > capacity):
    see ``GROW_HEADROOM``."""
    if GROW_HEADROOM:
        return max(int(need), int(GROW_HEADROOM * need))
    return max(int(need), int(1.5 * capacity))


# --------------------------------------------------------------------------------------------
# Data holders
# --------------------------------------------------------------------------------------------


class BVH(NamedTuple):
    """A linear BVH over ``n`` primitive boxes (arrays owned by the caller).

    Node index space: internal nodes ``0 .. n-2`` (root 0), leaf ``k`` is node ``n - 1 + k``.
    """

    node_lo: np.ndarray
    """Box lower corners [m], shape (2n-1, 3), float64."""
    node_hi: np.ndarray
    """Box upper corners [m], shape (2n-1, 3), float64."""
    child: np.ndarray
    """Children of internal node i (node indices), shape (n-1, 2), int64."""
    parent: np.ndarray
    """Parent node of every node, -1 at the root, shape (2n-1,), int64."""
    node_range: np.ndarray
    """First and last leaf position (Morton order) under each node, shape (2n-1, 2), int64."""
    leaf_prim: np.ndarray
    """Primitive index of leaf k, shape (n,), int64."""
    refit_order: np.ndarray
    """Internal nodes in refit order, shape (n-1,), int64: one run per parallel subtree (deepest
    first), then the nodes above the subtrees (deepest first)."""
    sub_ptr: np.ndarray
    """Start of each subtree run in ``refit_order``; the last entry starts the top part,
    shape (subtree_count+1,), int64."""
    max_depth: int
    """Depth of the deepest leaf (root has depth 0)."""
    build_cost: float
    """Normalised SAH cost (see :func:`bvh_cost`) right after the build."""

    @property
    def leaf_count(self) -> int:
        """Number of primitives (leaves)."""
        return int(self.leaf_prim.shape[0])


class HashGrid(NamedTuple):
    """A uniform hash grid over ``n`` points, bucketed by a counting sort (CSR layout)."""

    cell_size: float
    """Cell edge length [m]."""
    mask: int
    """Table size minus one (the table size is a power of two)."""
    bucket_start: np.ndarray
    """Start of each bucket in ``sorted_ids``, shape (table_size+1,), int64."""
    sorted_ids: np.ndarray
    """Point indices ordered by bucket, shape (n,), int64."""
    sorted_cell: np.ndarray
    """Integer cell coordinates of ``sorted_ids``' points, shape (n, 3), int64."""


class PairBuffer:
    """A growable ``(capacity, 2)`` int64 buffer reused by successive queries.

    A query given ``out=buffer`` returns a view ``buffer.data[:pair_count]``; the next query on the
    same buffer overwrites it. When a query needs more rows the buffer grows to
    ``grown_size(needed, capacity)`` (the only allocation; see ``GROW_HEADROOM``).
    """

    def __init__(self, capacity: int = 0):
        self.data = np.empty((int(capacity), 2), dtype=np.int64)
        #: pair count of the last tree-tree query on this buffer (0: none yet); sizes the
        #: single-pass traversal's scratch
        self.expected = 0
        self._scratch = np.empty((0, 2), dtype=np.int64)
        self._counts = np.empty(0, dtype=np.int64)

    def _zsort_keys(self, count: int):
        """Two int64 scratch arrays of ``count`` entries for :func:`zsort_pairs`."""
        k = getattr(self, "_keys", None)
        if k is None or count > k.shape[1]:
            n = grown_size(count, 0 if k is None else k.shape[1])
            k = self._keys = np.empty((2, n), dtype=np.int64)
        return k[0, :count], k[1, :count]

    def _sort_counts(self, count: int) -> np.ndarray:
        """An int64 scratch of ``count`` entries for :func:`sort_pairs`."""
        if count > self._counts.shape[0]:
            self._counts = np.empty(grown_size(count, self._counts.shape[0]), dtype=np.int64)
        return self._counts[:count]

    def scratch_rows(self, count: int) -> np.ndarray:
        """A ``(count, 2)`` scratch view for single-pass queries (grown like ``data``)."""
        if count > self._scratch.shape[0]:
            self._scratch = np.empty((grown_size(count, self._scratch.shape[0]), 2),
                                     dtype=np.int64)
        return self._scratch[:count]

    @property
    def capacity(self) -> int:
        return int(self.data.shape[0])

    def reserve(self, count: int) -> np.ndarray:
        """Return a ``(count, 2)`` view, growing the storage first if needed."""
        if count > self.data.shape[0]:
            self.data = np.empty((grown_size(count, self.data.shape[0]), 2), dtype=np.int64)
        return self.data[:count]


_DUMMY = np.empty((1, 2), dtype=np.int64)


def _reserve(out: PairBuffer | None, count: int) -> np.ndarray:
    if out is None:
        return np.empty((count, 2), dtype=np.int64)
    return out.reserve(count)


# --------------------------------------------------------------------------------------------
# Input normalisation (Python, O(1) per call)
# --------------------------------------------------------------------------------------------


def _as_positions(X, name):
    X = np.ascontiguousarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (vertex_count, 3), got {X.shape}")
    return X


def _as_prims(prims, name="prims"):
    P = np.asarray(prims)
    if P.ndim == 1:
        P = P.reshape(-1, 1)
    if P.ndim != 2 or P.shape[1] < 1:
        raise ValueError(f"{name}: expected shape (m, k) with k in 1..3, got {P.shape}")
    if P.size and not np.issubdtype(P.dtype, np.integer):
        raise ValueError(f"{name}: expected integer vertex indices, got dtype {P.dtype}")
    return np.ascontiguousarray(P, dtype=np.int64)


def _as_boxes(lo, hi):
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape:
        raise ValueError(f"lo/hi: expected two arrays of shape (m, 3), got {lo.shape} and {hi.shape}")
    return lo, hi


def _empty_prims():
    return np.zeros((0, 1), dtype=np.int64)


# --------------------------------------------------------------------------------------------
# Primitive boxes
# --------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _down(x):
    # a float <= x minus at least one ulp (outward rounding of an inflated lower bound)
    return x - (abs(x) * 2.220446049250313e-16 + 5e-324)


@njit(cache=True, inline="always")
def _up(x):
    return x + (abs(x) * 2.220446049250313e-16 + 5e-324)


@njit(parallel=True, cache=True)
def _prim_boxes_kernel(X0, X1, prims, thick, per_vertex, lo, hi):
    m = prims.shape[0]
    k = prims.shape[1]
    for i in prange(m):
        r = 0.0 if per_vertex else thick[0]
        v = prims[i, 0]
        x0 = min(X0[v, 0], X1[v, 0])
        y0 = min(X0[v, 1], X1[v, 1])
        z0 = min(X0[v, 2], X1[v, 2])
        x1 = max(X0[v, 0], X1[v, 0])
        y1 = max(X0[v, 1], X1[v, 1])
        z1 = max(X0[v, 2], X1[v, 2])
        if per_vertex:
            r = thick[v]
        for c in range(1, k):
            v = prims[i, c]
            x0 = min(x0, min(X0[v, 0], X1[v, 0]))
            y0 = min(y0, min(X0[v, 1], X1[v, 1]))
            z0 = min(z0, min(X0[v, 2], X1[v, 2]))
            x1 = max(x1, max(X0[v, 0], X1[v, 0]))
            y1 = max(y1, max(X0[v, 1], X1[v, 1]))
            z1 = max(z1, max(X0[v, 2], X1[v, 2]))
            if per_vertex:
                r = max(r, thick[v])
        if r > 0.0:
            x0 = _down(x0 - r)
            y0 = _down(y0 - r)
            z0 = _down(z0 - r)
            x1 = _up(x1 + r)
            y1 = _up(y1 + r)
            z1 = _up(z1 + r)
        lo[i, 0] = x0
        lo[i, 1] = y0
        lo[i, 2] = z0
        hi[i, 0] = x1
        hi[i, 1] = y1
        hi[i, 2] = z1


def primitive_boxes(X0, prims, X1=None, thickness=0.0, lo=None, hi=None):
    """Axis-aligned (swept) boxes of points, edges or triangles.

    Parameters
    ----------
    X0 : (vertex_count, 3) float64
        Vertex positions [m] at the start of the step.
    prims : (m, k) int
        Vertex indices of each primitive (k = 1, 2 or 3); a 1-D array means points.
    X1 : (vertex_count, 3) float64, optional
        Vertex positions [m] at the end of the step. The box is then the union of the boxes at
        both ends, which contains the whole linear motion. ``None``: static boxes of ``X0``.
    thickness : float or (vertex_count,) float64
        Inflation radius [m]; per vertex, a primitive uses the largest over its vertices.
    lo, hi : (m, 3) float64, optional
        Output arrays to fill in place (allocate once, reuse every substep).

    Returns
    -------
    lo, hi : (m, 3) float64 box corners [m].
    """
    X0 = _as_positions(X0, "X0")
    X1 = X0 if X1 is None else _as_positions(X1, "X1")
    if X1.shape != X0.shape:
        raise ValueError(f"X1: shape {X1.shape} differs from X0 {X0.shape}")
    P = _as_prims(prims)
    if P.size and (P.min() < 0 or P.max() >= X0.shape[0]):
        raise ValueError(f"prims: vertex index out of range 0..{X0.shape[0] - 1}")
    t = np.asarray(thickness, dtype=np.float64)
    if t.ndim == 0:
        per_vertex = False
        t = t.reshape(1)
    elif t.shape == (X0.shape[0],):
        per_vertex = True
        t = np.ascontiguousarray(t)
    else:
        raise ValueError(f"thickness: expected a scalar or shape ({X0.shape[0]},), got {t.shape}")
    if np.any(t < 0) or not np.all(np.isfinite(t)):
        raise ValueError("thickness: must be finite and >= 0")
    m = P.shape[0]
    if lo is None:
        lo = np.empty((m, 3), dtype=np.float64)
    if hi is None:
        hi = np.empty((m, 3), dtype=np.float64)
    for name, arr in (("lo", lo), ("hi", hi)):
        if arr.shape != (m, 3) or arr.dtype != np.float64 or not arr.flags.c_contiguous:
            raise ValueError(f"{name}: expected a C-contiguous float64 array of shape ({m}, 3)")
    _prim_boxes_kernel(X0, X1, P, t, per_vertex, lo, hi)
    return lo, hi


def mesh_edges(F) -> np.ndarray:
    """Unique undirected edges of a triangle mesh, shape (edge_count, 2), int64, rows (min, max),
    sorted lexicographically. Vectorised numpy (no Python loop over triangles)."""
    F = _as_prims(F, "F")
    if F.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.int64)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=0)
    e.sort(axis=1)
    return np.unique(e, axis=0)


# --------------------------------------------------------------------------------------------
# LBVH build (Karras 2012)
# --------------------------------------------------------------------------------------------


@njit(cache=True)
def _expand21(v):
    v &= 0x1FFFFF
    v = (v | (v << 32)) & 0x1F00000000FFFF
    v = (v | (v << 16)) & 0x1F0000FF0000FF
    v = (v | (v << 8)) & 0x100F00F00F00F00F
    v = (v | (v << 4)) & 0x10C30C30C30C30C3
    v = (v | (v << 2)) & 0x1249249249249249
    return v


@njit(cache=True)
def _morton_codes(lo, hi, codes):
    n = lo.shape[0]
    cmin = np.empty(3)
    cmax = np.empty(3)
    for a in range(3):
        cmin[a] = np.inf
        cmax[a] = -np.inf
    for i in range(n):
        for a in range(3):
            c = 0.5 * lo[i, a] + 0.5 * hi[i, a]
            if c < cmin[a]:
                cmin[a] = c
            if c > cmax[a]:
                cmax[a] = c
    scale = np.empty(3)
    for a in range(3):
        ext = cmax[a] - cmin[a]
        scale[a] = 2097151.0 / ext if ext > 0.0 else 0.0
    for i in range(n):
        code = 0
        for a in range(3):
            c = 0.5 * lo[i, a] + 0.5 * hi[i, a]
            q = int((c - cmin[a]) * scale[a])
            if q < 0:
                q = 0
            if q > 2097151:
                q = 2097151
            code |= _expand21(q) << (2 - a)
        codes[i] = code


@njit(cache=True)
def _highest_bit(x):
    # position of the highest set bit of x > 0 (x < 2**63)
    p = 0
    if x >= (1 << 32):
        x >>= 32
        p += 32
    if x >= (1 << 16):
        x >>= 16
        p += 16
    if x >= (1 << 8):
        x >>= 8
        p += 8
    if x >= (1 << 4):
        x >>= 4
        p += 4
    if x >= (1 << 2):
        x >>= 2
        p += 2
    if x >= 2:
        p += 1
    return p


@njit(cache=True)
def _delta(codes, n, i, j):
    # length of the common prefix of keys i and j (code, then position as a tie-break); -1 outside
    if j < 0 or j >= n:
        return -1
    x = codes[i] ^ codes[j]
    if x != 0:
        return 63 - _highest_bit(x)
    return 127 - _highest_bit(i ^ j)


@njit(parallel=True, cache=True)
def _karras_internal(codes, child, parent, node_range):
    n = codes.shape[0]
    base = n - 1
    node_range[base + n - 1, 0] = n - 1
    node_range[base + n - 1, 1] = n - 1
    for i in prange(n - 1):
        node_range[base + i, 0] = i
        node_range[base + i, 1] = i
        d = 1 if _delta(codes, n, i, i + 1) > _delta(codes, n, i, i - 1) else -1
        dmin = _delta(codes, n, i, i - d)
        lmax = 2
        while _delta(codes, n, i, i + lmax * d) > dmin:
            lmax *= 2
        l = 0
        t = lmax // 2
        while t >= 1:
            if _delta(codes, n, i, i + (l + t) * d) > dmin:
                l += t
            t //= 2
        j = i + l * d
        dnode = _delta(codes, n, i, j)
        s = 0
        t = l
        while True:
            t = (t + 1) // 2
            if _delta(codes, n, i, i + (s + t) * d) > dnode:
                s += t
            if t <= 1:
                break
        gamma = i + s * d + min(d, 0)
        first = min(i, j)
        last = max(i, j)
        left = gamma + base if first == gamma else gamma
        right = gamma + 1 + base if last == gamma + 1 else gamma + 1
        child[i, 0] = left
        child[i, 1] = right
        parent[left] = i
        parent[right] = i
        node_range[i, 0] = first
        node_range[i, 1] = last


@njit(cache=True)
def _refit_schedule(child, n, min_parallel, target):
    """Refit order of the internal nodes: split the tree at the shallowest depth that has at least
    ``target`` internal nodes; each subtree below the cut is a contiguous run of ``order``
    (deepest first), refit by one thread; the nodes above the cut follow, deepest first, refit
    serially. Trees with fewer than ``min_parallel`` internal nodes get no subtrees.
    Returns (order, sub_ptr, max_depth)."""
    n_int = n - 1
    depth = np.zeros(2 * n - 1, dtype=np.int64)
    queue = np.empty(2 * n - 1, dtype=np.int64)
    queue[0] = 0
    head = 0
    tail = 1
    max_depth = 0
    while head < tail:
        u = queue[head]
        head += 1
        if u < n_int:
            for c in range(2):
                w = child[u, c]
                depth[w] = depth[u] + 1
                if depth[w] > max_depth:
                    max_depth = depth[w]
                queue[tail] = w
                tail += 1
    per_depth = np.zeros(max_depth + 1, dtype=np.int64)
    for u in range(n_int):
        per_depth[depth[u]] += 1
    cut = -1
    if n_int >= min_parallel:
        for dd in range(max_depth + 1):
            if per_depth[dd] >= target:
                cut = dd
                break
    # subtree slot of each internal node (BFS order: parents before children); top slot = nsub
    slot = np.empty(max(n_int, 1), dtype=np.int64)
    nsub = per_depth[cut] if cut >= 0 else 0
    nxt = 0
    for q in range(tail):
        u = queue[q]
        if u >= n_int:
            continue
        if cut < 0 or depth[u] < cut:
            slot[u] = nsub
        elif depth[u] == cut:
            slot[u] = nxt
            nxt += 1
        else:
            slot[u] = -2
    # deeper nodes inherit their parent's slot (walk BFS order again, parents come first)
    for q in range(tail):
        u = queue[q]
        if u >= n_int:
            continue
        for c in range(2):
            w = child[u, c]
            if w < n_int and slot[w] == -2:
                slot[w] = slot[u]
    nb = (nsub + 1) * (max_depth + 1)
    cnt = np.zeros(nb + 1, dtype=np.int64)
    for u in range(n_int):
        cnt[slot[u] * (max_depth + 1) + (max_depth - depth[u]) + 1] += 1
    for b in range(nb):
        cnt[b + 1] += cnt[b]
    order = np.empty(n_int, dtype=np.int64)
    fill = cnt[:nb].copy()
    for u in range(n_int):
        b = slot[u] * (max_depth + 1) + (max_depth - depth[u])
        order[fill[b]] = u
        fill[b] += 1
    sub_ptr = np.empty(nsub + 1, dtype=np.int64)
    for sidx in range(nsub + 1):
        sub_ptr[sidx] = cnt[sidx * (max_depth + 1)]
    return order, sub_ptr, max_depth


@njit(cache=True, inline="always")
def _union_node(lo, hi, leaf_prim, node_lo, node_hi, child, base, u):
    l = child[u, 0]
    r = child[u, 1]
    if l >= base:
        p = leaf_prim[l - base]
        for a in range(3):
            node_lo[l, a] = lo[p, a]
            node_hi[l, a] = hi[p, a]
    if r >= base:
        p = leaf_prim[r - base]
        for a in range(3):
            node_lo[r, a] = lo[p, a]
            node_hi[r, a] = hi[p, a]
    for a in range(3):
        node_lo[u, a] = min(node_lo[l, a], node_lo[r, a])
        node_hi[u, a] = max(node_hi[l, a], node_hi[r, a])


@njit(parallel=True, cache=True)
def _refit_kernel(lo, hi, leaf_prim, node_lo, node_hi, child, order, sub_ptr):
    n = leaf_prim.shape[0]
    base = n - 1
    if n == 1:
        p = leaf_prim[0]
        for a in range(3):
            node_lo[0, a] = lo[p, a]
            node_hi[0, a] = hi[p, a]
        return
    nsub = sub_ptr.shape[0] - 1
    if nsub > 0:
        for sidx in prange(nsub):
            for t in range(sub_ptr[sidx], sub_ptr[sidx + 1]):
                _union_node(lo, hi, leaf_prim, node_lo, node_hi, child, base, order[t])
    for t in range(sub_ptr[nsub], n - 1):
        _union_node(lo, hi, leaf_prim, node_lo, node_hi, child, base, order[t])


@njit(cache=True)
def _cost_kernel(node_lo, node_hi, n_int):
    if n_int == 0:
        return 1.0
    total = 0.0
    for u in range(n_int):
        dx = node_hi[u, 0] - node_lo[u, 0]
        dy = node_hi[u, 1] - node_lo[u, 1]
        dz = node_hi[u, 2] - node_lo[u, 2]
        total += dx * dy + dy * dz + dz * dx
    dx = node_hi[0, 0] - node_lo[0, 0]
    dy = node_hi[0, 1] - node_lo[0, 1]
    dz = node_hi[0, 2] - node_lo[0, 2]
    root = dx * dy + dy * dz + dz * dx
    if root <= 0.0:
        return 1.0 if total <= 0.0 else np.inf
    return total / root


def build_bvh(lo, hi) -> BVH:
    """Build a linear BVH (Karras 2012, 63-bit Morton codes) over ``m`` boxes.

    Parameters
    ----------
    lo, hi : (m, 3) float64
        Primitive boxes [m], e.g. from :func:`primitive_boxes`. They are copied into the leaves.

    Returns
    -------
    BVH
        Arrays of the tree; see :class:`BVH`. ``m == 0`` gives an empty tree (queries return no pairs).
    """
    lo, hi = _as_boxes(lo, hi)
    n = lo.shape[0]
    if n == 0:
        z = np.zeros((0, 3))
        zi = np.zeros(0, dtype=np.int64)
        z2 = np.zeros((0, 2), np.int64)
        return BVH(z, z.copy(), z2, zi, z2.copy(), zi.copy(), zi.copy(), np.zeros(1, np.int64), 0, 1.0)
    codes = np.empty(n, dtype=np.int64)
    _morton_codes(lo, hi, codes)
    leaf_prim = np.argsort(codes, kind="stable").astype(np.int64)
    sorted_codes = np.ascontiguousarray(codes[leaf_prim])
    child = np.empty((n - 1, 2), dtype=np.int64)
    parent = np.empty(2 * n - 1, dtype=np.int64)
    parent[0] = -1
    node_range = np.empty((2 * n - 1, 2), dtype=np.int64)
    _karras_internal(sorted_codes, child, parent, node_range)
    order, sub_ptr, max_depth = _refit_schedule(child, n, _REFIT_MIN_PARALLEL, _REFIT_SUBTREES)
    node_lo = np.empty((2 * n - 1, 3))
    node_hi = np.empty((2 * n - 1, 3))
    _refit_kernel(lo, hi, leaf_prim, node_lo, node_hi, child, order, sub_ptr)
    cost = _cost_kernel(node_lo, node_hi, n - 1)
    return BVH(node_lo, node_hi, child, parent, node_range, leaf_prim, order, sub_ptr,
               int(max_depth), float(cost))


def refit_bvh(bvh: BVH, lo, hi) -> BVH:
    """Recompute every node box of ``bvh`` in place from new primitive boxes (same primitives,
    same order as at build). The topology is kept. Returns ``bvh``."""
    lo, hi = _as_boxes(lo, hi)
    if lo.shape[0] != bvh.leaf_count:
        raise ValueError(f"refit_bvh: {lo.shape[0]} boxes for a BVH of {bvh.leaf_count} leaves")
    if bvh.leaf_count:
        _refit_kernel(lo, hi, bvh.leaf_prim, bvh.node_lo, bvh.node_hi, bvh.child, bvh.refit_order,
                      bvh.sub_ptr)
    return bvh


@njit(parallel=True, cache=True)
def _st_prim_kernel(X0, X1, prims, thick, per_vertex, active, group, st):
    m = prims.shape[0]
    for i in prange(m):
        st[i, 12] = 1.0 if active.shape[0] == 0 or active[i] else 0.0
        st[i, 13] = 0.0 if group.shape[0] == 0 else float(group[i])
        r = 0.0 if per_vertex else thick[0]
        for a in range(3):
            st[i, a] = np.inf
            st[i, 3 + a] = -np.inf
            st[i, 6 + a] = np.inf
            st[i, 9 + a] = -np.inf
        for c in range(prims.shape[1]):
            v = prims[i, c]
            if per_vertex:
                r = max(r, thick[v])
            for a in range(3):
                d = X1[v, a] - X0[v, a]
                st[i, a] = min(st[i, a], X0[v, a])
                st[i, 3 + a] = max(st[i, 3 + a], X0[v, a])
                st[i, 6 + a] = min(st[i, 6 + a], d)
                st[i, 9 + a] = max(st[i, 9 + a], d)
        if r > 0.0:
            for a in range(3):
                st[i, a] = _down(st[i, a] - r)
                st[i, 3 + a] = _up(st[i, 3 + a] + r)


@njit(cache=True)
def _st_refit(st_prim, leaf_prim, child, order, node_st):
    n = leaf_prim.shape[0]
    base = n - 1
    for k in range(n):
        for j in range(14):
            node_st[base + k, j] = st_prim[leaf_prim[k], j]
    for t in range(n - 1):
        u = order[t]
        l = child[u, 0]
        r = child[u, 1]
        for j in range(3):
            node_st[u, j] = min(node_st[l, j], node_st[r, j])
            node_st[u, 3 + j] = max(node_st[l, 3 + j], node_st[r, 3 + j])
            node_st[u, 6 + j] = min(node_st[l, 6 + j], node_st[r, 6 + j])
            node_st[u, 9 + j] = max(node_st[l, 9 + j], node_st[r, 9 + j])
        node_st[u, 12] = max(node_st[l, 12], node_st[r, 12])
        node_st[u, 13] = node_st[l, 13] if node_st[l, 13] == node_st[r, 13] else -1.0


def spacetime_boxes(bvh: BVH, X0, prims, X1, thickness=0.0, active=None, group=None,
                    out=None) -> np.ndarray:
    """Space-time boxes of every node of ``bvh`` (built over the swept boxes of ``prims`` for
    the motion ``X0 -> X1``), for the tree-tree queries' ``st`` arguments: rows
    ``(lo0[3], hi0[3], dlo[3], dhi[3])``, the box [m] of the primitives at ``X0`` inflated by
    the thickness (as :func:`primitive_boxes`) and the box [m] of their vertices' displacements
    ``X1 - X0``; internal nodes hold the union of their children's. A query given them keeps a
    pair only if, on every axis, the gap between the start boxes can be closed by the relative
    displacement (``_st_overlap``: necessary for the primitives to come within the inflation
    anywhere along the linear motion), so primitives moving together (a falling sheet: large
    swept boxes, no relative motion) are not paired.
    Column 12 flags nodes holding an *active* primitive (``active``, (m,) bool; default all):
    two subtrees of inactive primitives only are never paired (e.g. the primitives of
    kinematic objects, which never collide with each other). Column 13: the primitives'
    ``group`` ((m,) int >= 0; default all 0), -1 for a node over several groups: only pairs of
    one group are tested in space-time, pairs of two groups by their swept boxes alone (e.g.
    the self pairs of each object: a solver's iterate may leave the linear motion, and
    objects pushing each other rely on the swept boxes). Shape (2 m - 1, 14); ``out`` (same
    shape) is filled in place when given."""
    X0 = _as_positions(X0, "X0")
    X1 = _as_positions(X1, "X1")
    P = _as_prims(prims)
    t = np.asarray(thickness, dtype=np.float64)
    per_vertex = t.ndim > 0
    t = np.ascontiguousarray(t.reshape(-1))
    m = P.shape[0]
    if m != bvh.leaf_count:
        raise ValueError(f"spacetime_boxes: {m} primitives for a BVH of {bvh.leaf_count} leaves")
    if m == 0:
        return np.zeros((0, 14))
    act = np.zeros(0, np.bool_) if active is None else np.ascontiguousarray(active, np.bool_)
    if act.shape[0] not in (0, m):
        raise ValueError(f"active: expected shape ({m},), got {act.shape}")
    grp = np.zeros(0, np.int64) if group is None else np.ascontiguousarray(group, np.int64)
    if grp.shape[0] not in (0, m) or (grp.shape[0] and grp.min() < 0):
        raise ValueError(f"group: expected shape ({m},) of ints >= 0")
    prim_st = np.empty((m, 14))
    _st_prim_kernel(X0, X1, P, t, per_vertex, act, grp, prim_st)
    node_st = np.empty((2 * m - 1, 14)) if out is None else out
    _st_refit(prim_st, bvh.leaf_prim, bvh.child, bvh.refit_order, node_st)
    return node_st


def bvh_cost(bvh: BVH) -> float:
    """Normalised SAH cost: sum of the internal nodes' surface areas over the root's (>= 1 for
    n >= 2; 1.0 for fewer than two leaves). Grows when refits loosen the tree."""
    return float(_cost_kernel(bvh.node_lo, bvh.node_hi, max(bvh.leaf_count - 1, 0)))


def needs_rebuild(bvh: BVH, factor: float = 1.5) -> bool:
    """True when :func:`bvh_cost` exceeds ``factor`` times its value at build."""
    return bvh_cost(bvh) > factor * bvh.build_cost


def update_bvh(bvh: BVH | None, lo, hi, factor: float = 1.5) -> BVH:
    """Refit ``bvh`` to new boxes, or build a new one when ``bvh`` is None, has a different size,
    or :func:`needs_rebuild` says the refit tree has degraded by more than ``factor``."""
    lo, hi = _as_boxes(lo, hi)
    if bvh is None or bvh.leaf_count != lo.shape[0]:
        return build_bvh(lo, hi)
    refit_bvh(bvh, lo, hi)
    if needs_rebuild(bvh, factor):
        return build_bvh(lo, hi)
    return bvh


class BVHCache:
    """BVHs and box arrays kept between detection passes (substeps, collision rounds).

    :meth:`update` refits the tree stored under a key to new boxes and rebuilds it only when its
    SAH cost has grown by more than ``factor`` over its value at build (:func:`update_bvh`) or
    the primitive count changed; :meth:`boxes` hands out the same ``lo``/``hi`` arrays every
    call. The candidate *set* of a query does not depend on the tree (box overlap is exact on
    the leaf boxes); the order of the rows does (it follows the tree's leaf order), so a
    refit tree lists the same pairs in a different order than a fresh build would.
    """

    #: refit kept trees (True, the default) or build every call (False, for A/B measurements).
    #: Measured in the collision contacts on cloth_sphere_64 (1 thread, 10 frames, interleaved):
    #: refitting saved 5 % of the CPU time per frame but changes the order of the candidates,
    #: hence the Gauss-Seidel order of the contacts (results no longer bitwise equal to a fresh
    #: build, and a run resumed from a checkpoint would differ from an uninterrupted one), so
    #: the contacts do not use it.
    reuse = True

    def __init__(self, factor: float = 1.5):
        self.factor = float(factor)
        self.trees: dict = {}
        self._boxes: dict = {}
        self.builds = 0
        self.refits = 0

    def boxes(self, key, count: int):
        """Reused ``(count, 3)`` float64 ``lo``, ``hi`` arrays for key."""
        b = self._boxes.get(key)
        if b is None or b[0].shape[0] != count:
            b = self._boxes[key] = (np.empty((count, 3)), np.empty((count, 3)))
        return b

    def update(self, key, lo, hi) -> BVH:
        """The tree of key fitted to boxes lo, hi (refit, or built when missing or degraded)."""
        old = self.trees.get(key) if BVHCache.reuse else None
        if old is not None and old.leaf_count == lo.shape[0]:
            refit_bvh(old, lo, hi)
            if not needs_rebuild(old, self.factor):
                self.refits += 1
                return old
        self.builds += 1
        tree = self.trees[key] = build_bvh(lo, hi)
        return tree


def bvh_cache(owner) -> BVHCache:
    """The :class:`BVHCache` attached to ``owner`` (an object with a ``__dict__``), created on
    first use."""
    c = owner.__dict__.get("_bvh_cache")
    if c is None:
        c = owner.__dict__["_bvh_cache"] = BVHCache()
    return c


# --------------------------------------------------------------------------------------------
# BVH queries
# --------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _share_vertex(pa, i, pb, j):
    for x in range(pa.shape[1]):
        v = pa[i, x]
        for y in range(pb.shape[1]):
            if v == pb[j, y]:
                return True
    return False


@njit(cache=True)
def _query_one(x0, y0, z0, x1, y1, z1, node_lo, node_hi, child, leaf_prim, stack, k, pos, out, fill):
    """Box k against the tree from the root; returns the number of overlapping leaves."""
    base = leaf_prim.shape[0] - 1
    cnt = 0
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        u = stack[sp]
        if (node_lo[u, 0] > x1 or node_hi[u, 0] < x0 or node_lo[u, 1] > y1
                or node_hi[u, 1] < y0 or node_lo[u, 2] > z1 or node_hi[u, 2] < z0):
            continue
        if u >= base:
            if fill:
                out[pos, 0] = k
                out[pos, 1] = leaf_prim[u - base]
                pos += 1
            cnt += 1
        else:
            stack[sp] = child[u, 1]
            stack[sp + 1] = child[u, 0]
            sp += 2
    return cnt


@njit(parallel=True, cache=True)
def _query_kernel(q_lo, q_hi, node_lo, node_hi, child, leaf_prim, stack_size, counts, offsets,
                  out, fill):
    """Boxes q (k = 0..nq-1) against a tree, depth-first from the root; rows (k, prim)."""
    nq = q_lo.shape[0]
    nchunks = min(nq, _CHUNKS)
    chunk = (nq + nchunks - 1) // max(nchunks, 1)
    for c in prange(nchunks):
        stack = np.empty(stack_size, dtype=np.int64)
        for k in range(c * chunk, min(nq, (c + 1) * chunk)):
            pos = offsets[k] if fill else 0
            cnt = _query_one(q_lo[k, 0], q_lo[k, 1], q_lo[k, 2], q_hi[k, 0], q_hi[k, 1], q_hi[k, 2],
                             node_lo, node_hi, child, leaf_prim, stack, k, pos, out, fill)
            if not fill:
                counts[k] = cnt


def _run_query(q_lo, q_hi, bvh, out):
    nq = q_lo.shape[0]
    if nq == 0 or bvh.leaf_count == 0:
        return _reserve(out, 0)
    stack_size = bvh.max_depth + 2
    counts = np.empty(nq, dtype=np.int64)
    offsets = np.zeros(nq, dtype=np.int64)
    dummy = np.empty((1, 2), dtype=np.int64)
    args = (q_lo, q_hi, bvh.node_lo, bvh.node_hi, bvh.child, bvh.leaf_prim, stack_size, counts,
            offsets)
    _query_kernel(*args, dummy, False)
    np.cumsum(counts[:-1], out=offsets[1:])
    total = int(offsets[-1] + counts[-1])
    pairs = _reserve(out, total)
    if total:
        _query_kernel(*args, pairs, True)
    return pairs


@njit(cache=True, inline="always")
def _overlap(lo_a, hi_a, a, lo_b, hi_b, b):
    return not (lo_a[a, 0] > hi_b[b, 0] or hi_a[a, 0] < lo_b[b, 0] or lo_a[a, 1] > hi_b[b, 1]
                or hi_a[a, 1] < lo_b[b, 1] or lo_a[a, 2] > hi_b[b, 2] or hi_a[a, 2] < lo_b[b, 2])


@njit(cache=True, inline="always")
def _st_overlap(st_a, a, st_b, b):
    """Can the space-time boxes of nodes a and b (rows of ``spacetime_boxes``: box at the start
    ``lo0, hi0`` and box of the displacements ``dlo, dhi``) overlap during the motion? At time
    t in [0, 1] every primitive under a node lies in [lo0 + t dlo, hi0 + t dhi]; on each axis
    the gap between the two boxes at the start must be closable by their relative
    displacement: ``lo0_a - hi0_b + min(0, dlo_a - dhi_b) <= 0`` and the mirror condition
    (per axis, not at a common time t: measured on a frame-12 detection of cloth_sphere_64,
    3 % more edge-edge candidates than the common-time test, whose divisions made the
    traversal 15 % slower than with swept boxes alone; this one is not). A common translation of
    both cancels: a flat sheet falling as a whole keeps the boxes of its resting shape.
    _ST_TOL [m] of slack covers rounding."""
    for k in range(3):
        if st_a[a, k] - st_b[b, 3 + k] + min(0.0, st_a[a, 6 + k] - st_b[b, 9 + k]) > _ST_TOL:
            return False
        if st_a[a, 3 + k] - st_b[b, k] + max(0.0, st_a[a, 9 + k] - st_b[b, 6 + k]) < -_ST_TOL:
            return False
    return True


@njit(cache=True, inline="always")
def _ovl(lo_a, hi_a, st_a, a, lo_b, hi_b, st_b, b):
    """Swept-box overlap of nodes a and b and, with space-time boxes (``st_a`` nonempty), that
    one of them holds an active primitive and, for two nodes of one group, their space-time
    overlap (``_st_overlap``)."""
    if not _overlap(lo_a, hi_a, a, lo_b, hi_b, b):
        return False
    if st_a.shape[0] == 0:
        return True
    if st_a[a, 12] == 0.0 and st_b[b, 12] == 0.0:
        return False
    if st_a[a, 13] < 0.0 or st_a[a, 13] != st_b[b, 13]:
        return True  # two groups: swept boxes only
    return _st_overlap(st_a, a, st_b, b)


@njit(cache=True, inline="always")
def _split_a(lo_a, hi_a, range_a, a, lo_b, hi_b, range_b, b):
    """Descend into node a (True) or node b (False) of an overlapping pair that is not a pair of
    clusters: never into a cluster, else into the node with the larger box."""
    if range_b[b, 1] - range_b[b, 0] < _CLUSTER:
        return True
    if range_a[a, 1] - range_a[a, 0] < _CLUSTER:
        return False
    ea = hi_a[a, 0] - lo_a[a, 0] + hi_a[a, 1] - lo_a[a, 1] + hi_a[a, 2] - lo_a[a, 2]
    eb = hi_b[b, 0] - lo_b[b, 0] + hi_b[b, 1] - lo_b[b, 1] + hi_b[b, 2] - lo_b[b, 2]
    return ea >= eb


@njit(cache=True)
def _tt_tasks(lo_a, hi_a, child_a, range_a, lo_b, hi_b, child_b, range_b, self_mode, target,
              st_a, st_b):
    """Expand the top of the simultaneous traversal level by level into at least ``target``
    independent tasks (node pairs; in self mode a pair (u, u) means "u against itself").
    Invariant: every pair task (a != b) has overlapping boxes."""
    cap = 3 * target + 3
    ta = np.empty(cap, dtype=np.int64)
    tb = np.empty(cap, dtype=np.int64)
    na = np.empty(cap, dtype=np.int64)
    nb = np.empty(cap, dtype=np.int64)
    ta[0] = 0
    tb[0] = 0
    nt = 1
    if not self_mode and not _overlap(lo_a, hi_a, 0, lo_b, hi_b, 0):
        nt = 0
    while 0 < nt < target:
        m = 0
        grew = False
        for t in range(nt):
            a = ta[t]
            b = tb[t]
            if self_mode and a == b:
                if range_a[a, 1] - range_a[a, 0] >= _CLUSTER:
                    l = child_a[a, 0]
                    r = child_a[a, 1]
                    na[m] = l
                    nb[m] = l
                    na[m + 1] = r
                    nb[m + 1] = r
                    m += 2
                    if _overlap(lo_a, hi_a, l, lo_a, hi_a, r):
                        na[m] = l
                        nb[m] = r
                        m += 1
                    grew = True
                else:
                    na[m] = a
                    nb[m] = b
                    m += 1
                continue
            if range_a[a, 1] - range_a[a, 0] < _CLUSTER and range_b[b, 1] - range_b[b, 0] < _CLUSTER:
                na[m] = a
                nb[m] = b
                m += 1
                continue
            if _split_a(lo_a, hi_a, range_a, a, lo_b, hi_b, range_b, b):
                for c in range(2):
                    w = child_a[a, c]
                    if _overlap(lo_a, hi_a, w, lo_b, hi_b, b):
                        na[m] = w
                        nb[m] = b
                        m += 1
            else:
                for c in range(2):
                    w = child_b[b, c]
                    if _overlap(lo_a, hi_a, a, lo_b, hi_b, w):
                        na[m] = a
                        nb[m] = w
                        m += 1
            grew = True
        for t in range(m):
            ta[t] = na[t]
            tb[t] = nb[t]
        nt = m
        if not grew:
            break
    return ta[:nt].copy(), tb[:nt].copy()


@njit(cache=True)
def _tt_task(lo_a, hi_a, child_a, range_a, leaf_a, lo_b, hi_b, child_b, range_b, leaf_b, prims_a,
             prims_b, st_a, st_b, skip_shared, self_mode, a0, b0, sa, sb, pos, out, fill, lim):
    """Depth-first simultaneous traversal from the node pair (a0, b0); returns the pair count.
    In fill mode the pairs are written to ``out`` from row ``pos`` on, up to row ``lim - 1``
    (pairs beyond are counted, not written). Pairs of small subtrees
    (clusters of at most _CLUSTER leaves, contiguous in Morton order) are tested leaf by leaf."""
    base_a = child_a.shape[0]
    base_b = child_b.shape[0]
    sa[0] = a0
    sb[0] = b0
    sp = 1
    cnt = 0
    while sp > 0:
        sp -= 1
        a = sa[sp]
        b = sb[sp]
        if st_a.shape[0] and st_a[a, 12] == 0.0 and st_b[b, 12] == 0.0:
            continue  # two subtrees of inactive primitives only
        fa = range_a[a, 0]
        la = range_a[a, 1]
        if self_mode and a == b:
            if la - fa < _CLUSTER:
                for i in range(fa, la + 1):
                    for j in range(i + 1, la + 1):
                        if _ovl(lo_a, hi_a, st_a, base_a + i, lo_a, hi_a, st_a, base_a + j):
                            pa = leaf_a[i]
                            pb = leaf_a[j]
                            if skip_shared and _share_vertex(prims_a, pa, prims_a, pb):
                                continue
                            if fill and pos < lim:
                                out[pos, 0] = min(pa, pb)
                                out[pos, 1] = max(pa, pb)
                                pos += 1
                            cnt += 1
                continue
            l = child_a[a, 0]
            r = child_a[a, 1]
            sa[sp] = r
            sb[sp] = r
            sp += 1
            if _overlap(lo_a, hi_a, l, lo_a, hi_a, r):
                sa[sp] = l
                sb[sp] = r
                sp += 1
            sa[sp] = l
            sb[sp] = l
            sp += 1
            continue
        fb = range_b[b, 0]
        lb = range_b[b, 1]
        if la - fa < _CLUSTER and lb - fb < _CLUSTER:
            if st_a.shape[0] and st_a[a, 13] >= 0.0 and st_a[a, 13] == st_b[b, 13] \
                    and not _st_overlap(st_a, a, st_b, b):
                continue  # the two clusters never overlap at a common time
            for i in range(fa, la + 1):
                if la > fa and not _ovl(lo_a, hi_a, st_a, base_a + i, lo_b, hi_b, st_b, b):
                    continue
                for j in range(fb, lb + 1):
                    if _ovl(lo_a, hi_a, st_a, base_a + i, lo_b, hi_b, st_b, base_b + j):
                        pa = leaf_a[i]
                        pb = leaf_b[j]
                        if skip_shared and _share_vertex(prims_a, pa, prims_b, pb):
                            continue
                        if fill and pos < lim:
                            if self_mode and pb < pa:
                                out[pos, 0] = pb
                                out[pos, 1] = pa
                            else:
                                out[pos, 0] = pa
                                out[pos, 1] = pb
                            pos += 1
                        cnt += 1
            continue
        if _split_a(lo_a, hi_a, range_a, a, lo_b, hi_b, range_b, b):
            w0 = child_a[a, 0]
            w1 = child_a[a, 1]
            if _overlap(lo_a, hi_a, w1, lo_b, hi_b, b):
                sa[sp] = w1
                sb[sp] = b
                sp += 1
            if _overlap(lo_a, hi_a, w0, lo_b, hi_b, b):
                sa[sp] = w0
                sb[sp] = b
                sp += 1
        else:
            w0 = child_b[b, 0]
            w1 = child_b[b, 1]
            if _overlap(lo_a, hi_a, a, lo_b, hi_b, w1):
                sa[sp] = a
                sb[sp] = w1
                sp += 1
            if _overlap(lo_a, hi_a, a, lo_b, hi_b, w0):
                sa[sp] = a
                sb[sp] = w0
                sp += 1
    return cnt


@njit(parallel=True, cache=True)
def _tt_kernel(lo_a, hi_a, child_a, range_a, leaf_a, lo_b, hi_b, child_b, range_b, leaf_b,
               prims_a, prims_b, st_a, st_b, skip_shared, self_mode, task_a, task_b, stack_size,
               task_order, counts, offsets, out, fill):
    """Simultaneous depth-first traversal of two trees (or of one tree against itself) from
    each task. Only overlapping node pairs are expanded, the larger node is split first.
    Pair tasks (a, b) are tested for overlap before being pushed; self tasks (u, u) spawn
    (l, l), (l, r), (r, r). Leaf pairs are counted (count pass) or written (fill pass)."""
    ntask = task_a.shape[0]
    for it in prange(ntask):
        t = task_order[it]
        sa = np.empty(stack_size, dtype=np.int64)
        sb = np.empty(stack_size, dtype=np.int64)
        pos = offsets[t] if fill else 0
        cnt = _tt_task(lo_a, hi_a, child_a, range_a, leaf_a, lo_b, hi_b, child_b, range_b, leaf_b,
                       prims_a, prims_b, st_a, st_b, skip_shared, self_mode, task_a[t], task_b[t],
                       sa, sb, pos, out, fill, _NO_LIMIT)
        if not fill:
            counts[t] = cnt


@njit(parallel=True, cache=True)
def _tt_kernel_once(lo_a, hi_a, child_a, range_a, leaf_a, lo_b, hi_b, child_b, range_b, leaf_b,
                    prims_a, prims_b, st_a, st_b, skip_shared, self_mode, task_a, task_b,
                    stack_size, task_order, counts, starts, cap, scratch):
    """One traversal pass. The tasks, in ``task_order`` (shuffled, so every slot gets a similar
    mix of heavy and light tasks), are cut into ``scratch.shape[0] // cap`` equal runs; run c
    writes its tasks' pairs one after the other into rows ``c * cap .. (c + 1) * cap - 1`` of
    ``scratch``. ``counts[t]``: pairs of task t; ``starts[t]``: its first scratch row, or -1 if
    they did not fit (that task is traversed again)."""
    ntask = task_a.shape[0]
    nslot = scratch.shape[0] // cap
    per = (ntask + nslot - 1) // nslot
    for c in prange(nslot):
        sa = np.empty(stack_size, dtype=np.int64)
        sb = np.empty(stack_size, dtype=np.int64)
        pos = c * cap
        end = (c + 1) * cap
        for it in range(c * per, min(ntask, (c + 1) * per)):
            t = task_order[it]
            cnt = _tt_task(lo_a, hi_a, child_a, range_a, leaf_a, lo_b, hi_b, child_b, range_b,
                           leaf_b, prims_a, prims_b, st_a, st_b, skip_shared, self_mode,
                           task_a[t], task_b[t], sa, sb, pos, scratch, True, end)
            counts[t] = cnt
            if pos + cnt <= end:
                starts[t] = pos
                pos += cnt
            else:
                starts[t] = -1


@njit(parallel=True, cache=True)
def _tt_gather(scratch, starts, counts, offsets, out):
    """Copy every stored task's pairs from the scratch to its place in ``out``."""
    for t in prange(counts.shape[0]):
        src = starts[t]
        if src < 0:
            continue
        dst = offsets[t]
        for r in range(counts[t]):
            out[dst + r, 0] = scratch[src + r, 0]
            out[dst + r, 1] = scratch[src + r, 1]


_ORDERS: dict = {}
#: one thread traverses the tasks in their order (neighbouring tasks touch neighbouring nodes):
#: measured on the 64 x 64 drop's edge-edge self queries (frame 10, 1 thread) 7-15 % less time
#: than the shuffled order, the same pairs in the same order; per frame (``graphs/bench/
#: collision_scaling.py --ab --ab-flag broadphase.SEQUENTIAL_ONE_THREAD``, 1 thread, median
#: per-frame CPU ratio) 0.946 at 64 x 64 and 0.976 at 128 x 128. False: shuffled always
SEQUENTIAL_ONE_THREAD = True


def _task_order(n):
    """A fixed pseudo-random permutation of n tasks. prange hands each thread a contiguous block
    of iterations; shuffling spreads spatially clustered heavy tasks over the threads. Results
    stay at their task's offset, so the output order does not depend on it. Cached per n. With
    one thread (``SEQUENTIAL_ONE_THREAD``) the tasks in their order."""
    seq = SEQUENTIAL_ONE_THREAD and get_num_threads() == 1
    order = _ORDERS.get((n, seq))
    if order is None:
        if len(_ORDERS) > 256:
            _ORDERS.clear()
        order = _ORDERS[n, seq] = (np.arange(n, dtype=np.int64) if seq else
                                   np.random.default_rng(12345).permutation(n).astype(np.int64))
    return order


def _run_tt(bvh_a, bvh_b, prims_a, prims_b, skip_shared, self_mode, out, st_a=None,
            st_b=None):
    if bvh_a.leaf_count == 0 or bvh_b.leaf_count == 0:
        return _reserve(out, 0)
    if st_a is None or st_b is None:
        st_a = st_b = _NO_ST
    elif (st_a.shape != (2 * bvh_a.leaf_count - 1, 14)
          or st_b.shape != (2 * bvh_b.leaf_count - 1, 14)):
        raise ValueError("st: expected the spacetime_boxes of the trees")
    task_a, task_b = _tt_tasks(bvh_a.node_lo, bvh_a.node_hi, bvh_a.child, bvh_a.node_range,
                               bvh_b.node_lo, bvh_b.node_hi, bvh_b.child, bvh_b.node_range,
                               self_mode, _TASKS, st_a, st_b)
    nt = task_a.shape[0]
    if nt == 0:
        return _reserve(out, 0)
    stack_size = 2 * (bvh_a.max_depth + bvh_b.max_depth) + 8
    counts = np.empty(nt, dtype=np.int64)
    offsets = np.zeros(nt, dtype=np.int64)
    args = (bvh_a.node_lo, bvh_a.node_hi, bvh_a.child, bvh_a.node_range, bvh_a.leaf_prim,
            bvh_b.node_lo, bvh_b.node_hi, bvh_b.child, bvh_b.node_range, bvh_b.leaf_prim,
            prims_a, prims_b, st_a, st_b, skip_shared, self_mode, task_a, task_b,
            stack_size, _task_order(nt), counts)
    if out is not None and out.expected > 0:
        # one traversal into per-task slots of a reused scratch sized from the previous query
        # of this buffer; only tasks that overflow their slot are traversed again
        nslot = min(_SLOTS, nt, _SLOTS_PER_THREAD * get_num_threads())
        cap = (2 * out.expected) // nslot + 64
        scratch = out.scratch_rows(nslot * cap)
        starts = np.empty(nt, dtype=np.int64)
        _tt_kernel_once(*args, starts, cap, scratch)
        np.cumsum(counts[:-1], out=offsets[1:])
        total = int(offsets[-1] + counts[-1])
        pairs = _reserve(out, total)
        _tt_gather(scratch, starts, counts, offsets, pairs)
        redo = np.flatnonzero(starts < 0)
        if len(redo):
            args = args[:-5] + (task_a[redo], task_b[redo], stack_size,
                                np.arange(len(redo), dtype=np.int64), counts[redo])
            _tt_kernel(*args, offsets[redo], pairs, True)
        out.expected = max(total, 1)
        return pairs
    _tt_kernel(*args, offsets, _DUMMY, False)
    np.cumsum(counts[:-1], out=offsets[1:])
    total = int(offsets[-1] + counts[-1])
    pairs = _reserve(out, total)
    if total:
        _tt_kernel(*args, offsets, pairs, True)
    if out is not None:
        out.expected = max(total, 1)
    return pairs


def query_self(bvh: BVH, prims=None, out: PairBuffer | None = None, st=None) -> np.ndarray:
    """Candidate pairs within one primitive set (edge-edge, triangle-triangle self collision).

    Parameters
    ----------
    bvh : BVH over the boxes of ``prims``.
    prims : (m, k) int, optional
        Vertex indices of the primitives; pairs that share a vertex are skipped. ``None``: no skip.
    out : PairBuffer, optional
        Reused output storage.
    st : (2 m - 1, 14) float64, optional
        The tree's :func:`spacetime_boxes`: pairs must also overlap at a common time.

    Returns
    -------
    (pair_count, 2) int64, rows ``(i, j)`` with ``i < j`` (primitive indices), each overlapping
    unordered pair once.
    """
    if bvh.leaf_count == 0:
        return _reserve(out, 0)
    if prims is None:
        P, skip = _empty_prims(), False
    else:
        P, skip = _as_prims(prims), True
        if P.shape[0] != bvh.leaf_count:
            raise ValueError(f"query_self: {P.shape[0]} primitives for a BVH of {bvh.leaf_count} leaves")
    return _run_tt(bvh, bvh, P, P, skip, True, out, st, st)


def query_self_ee(bvh_e: BVH, E, out: PairBuffer | None = None) -> np.ndarray:
    """Edge-edge candidate pairs for self collision: :func:`query_self` over the edges ``E``
    ((edge_count, 2) int, e.g. from :func:`mesh_edges`); rows ``(i, j)``, ``i < j`` edge indices,
    edges sharing a vertex skipped."""
    E = _as_prims(E, "E")
    if E.shape[0] and E.shape[1] != 2:
        raise ValueError(f"E: expected shape (edge_count, 2), got {E.shape}")
    return query_self(bvh_e, E, out=out)


def query_pairs(bvh_a: BVH, bvh_b: BVH, prims_a=None, prims_b=None,
                out: PairBuffer | None = None, st_a=None, st_b=None) -> np.ndarray:
    """Candidate pairs between two primitive sets (e.g. cloth vertices vs collider triangles).

    The two trees are traversed simultaneously. If both ``prims_a`` and ``prims_b`` are given
    they must use the same vertex numbering, and pairs sharing a vertex are skipped (e.g.
    vertices vs triangles of one mesh). With both trees' :func:`spacetime_boxes` (``st_a``,
    ``st_b``) a pair must also overlap at a common time of the motion.

    Returns
    -------
    (pair_count, 2) int64, rows ``(prim_a, prim_b)``.
    """
    if (prims_a is None) != (prims_b is None):
        raise ValueError("query_pairs: give both prims_a and prims_b, or neither")
    if prims_a is None:
        Pa = Pb = _empty_prims()
        skip = False
    else:
        Pa, Pb, skip = _as_prims(prims_a, "prims_a"), _as_prims(prims_b, "prims_b"), True
        if Pa.shape[0] != bvh_a.leaf_count or Pb.shape[0] != bvh_b.leaf_count:
            raise ValueError("query_pairs: prims_a/prims_b sizes differ from the BVH leaf counts")
    if bvh_a.leaf_count == 0 or bvh_b.leaf_count == 0:
        return _reserve(out, 0)
    return _run_tt(bvh_a, bvh_b, Pa, Pb, skip, False, out, st_a, st_b)


def query_self_vf(bvh_v: BVH, bvh_f: BVH, F, vertices=None, out: PairBuffer | None = None) -> np.ndarray:
    """Vertex-triangle candidate pairs for self collision of one mesh.

    Parameters
    ----------
    bvh_v : BVH over the point boxes of ``vertices`` (default: all vertices ``0..n-1`` in order).
    bvh_f : BVH over the triangle boxes of ``F``.
    F : (face_count, 3) int, the triangles (same vertex numbering).
    vertices : (n,) int, optional, the vertex index of each point leaf.

    Returns
    -------
    (pair_count, 2) int64, rows ``(vertex, face)``; a vertex is never paired with its own triangles.
    """
    if vertices is None:
        vertices = np.arange(bvh_v.leaf_count, dtype=np.int64)
    return query_pairs(bvh_v, bvh_f, _as_prims(vertices, "vertices"), F, out=out)


def query_boxes(bvh: BVH, lo, hi, out: PairBuffer | None = None) -> np.ndarray:
    """Boxes ``(m, 3)`` against a BVH; rows ``(box_index, prim)`` for every overlap."""
    lo, hi = _as_boxes(lo, hi)
    return _run_query(lo, hi, bvh, out)


# --------------------------------------------------------------------------------------------
# Uniform hash grid
# --------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _hash3(i, j, k, mask):
    return ((i * 73856093) ^ (j * 19349663) ^ (k * 83492791)) & mask


@njit(cache=True)
def _grid_build_kernel(P, h, mask, bucket_start, sorted_ids, sorted_cell):
    n = P.shape[0]
    keys = np.empty(n, dtype=np.int64)
    cells = np.empty((n, 3), dtype=np.int64)
    bucket_start[:] = 0
    for i in range(n):
        for a in range(3):
            cells[i, a] = int(np.floor(P[i, a] / h))
        key = _hash3(cells[i, 0], cells[i, 1], cells[i, 2], mask)
        keys[i] = key
        bucket_start[key + 1] += 1
    for b in range(mask + 1):
        bucket_start[b + 1] += bucket_start[b]
    fill = bucket_start[:-1].copy()
    for i in range(n):
        s = fill[keys[i]]
        fill[keys[i]] += 1
        sorted_ids[s] = i
        for a in range(3):
            sorted_cell[s, a] = cells[i, a]


def build_hash_grid(P, cell_size: float, table_size: int | None = None) -> HashGrid:
    """Bin points ``P`` (n, 3) [m] into a uniform hash grid of cubic cells ``cell_size`` [m].

    ``table_size`` is rounded up to a power of two; default: the smallest >= 2 n.
    For :func:`hash_grid_pairs` with radius r, ``cell_size`` about r is a good choice.
    """
    P = _as_positions(P, "P")
    h = float(cell_size)
    if not (h > 0.0 and np.isfinite(h)):
        raise ValueError(f"cell_size: must be > 0 and finite (got {cell_size})")
    if not np.all(np.isfinite(P)):
        raise ValueError("P: positions must be finite")
    n = P.shape[0]
    want = max(2 * n, 1) if table_size is None else max(int(table_size), 1)
    size = 1 << int(np.ceil(np.log2(want))) if want > 1 else 1
    bucket_start = np.zeros(size + 1, dtype=np.int64)
    sorted_ids = np.empty(n, dtype=np.int64)
    sorted_cell = np.empty((n, 3), dtype=np.int64)
    _grid_build_kernel(P, h, size - 1, bucket_start, sorted_ids, sorted_cell)
    return HashGrid(h, size - 1, bucket_start, sorted_ids, sorted_cell)


@njit(cache=True, inline="always")
def _grid_candidate(P, i, j, k, lo, hi, r2, mode):
    if mode == 0:
        if j <= i:
            return False
        dx = P[i, 0] - P[j, 0]
        dy = P[i, 1] - P[j, 1]
        dz = P[i, 2] - P[j, 2]
        return dx * dx + dy * dy + dz * dz <= r2
    return not (P[j, 0] < lo[0] or P[j, 0] > hi[0] or P[j, 1] < lo[1] or P[j, 1] > hi[1]
                or P[j, 2] < lo[2] or P[j, 2] > hi[2])


@njit(cache=True)
def _grid_query_one(P, h, mask, bucket_start, sorted_ids, sorted_cell, q_lo, q_hi, q_pt, radius,
                    mode, k, lo, hi, clo, chi, offsets, out, fill):
    """Candidates of query k (see _grid_query_kernel); returns their number."""
    npts = sorted_ids.shape[0]
    r2 = radius * radius
    i = -1
    if mode == 0:
        i = q_pt[k]
        for a in range(3):
            x = P[i, a]
            pad = (abs(x) + radius) * 1e-15
            lo[a] = x - radius - pad
            hi[a] = x + radius + pad
    else:
        for a in range(3):
            lo[a] = q_lo[k, a]
            hi[a] = q_hi[k, a]
    ncell = 1.0
    for a in range(3):
        clo[a] = int(np.floor(lo[a] / h))
        chi[a] = int(np.floor(hi[a] / h))
        ncell *= chi[a] - clo[a] + 1
    first = i if mode == 0 else k
    cnt = 0
    pos = offsets[k] if fill else 0
    if ncell > npts:
        # the query spans more cells than there are points: scan the points instead
        for s in range(npts):
            j = sorted_ids[s]
            if _grid_candidate(P, i, j, k, lo, hi, r2, mode):
                if fill:
                    out[pos, 0] = first
                    out[pos, 1] = j
                    pos += 1
                cnt += 1
        return cnt
    for cx in range(clo[0], chi[0] + 1):
        for cy in range(clo[1], chi[1] + 1):
            for cz in range(clo[2], chi[2] + 1):
                b = _hash3(cx, cy, cz, mask)
                for s in range(bucket_start[b], bucket_start[b + 1]):
                    if sorted_cell[s, 0] != cx or sorted_cell[s, 1] != cy or sorted_cell[s, 2] != cz:
                        continue
                    j = sorted_ids[s]
                    if _grid_candidate(P, i, j, k, lo, hi, r2, mode):
                        if fill:
                            out[pos, 0] = first
                            out[pos, 1] = j
                            pos += 1
                        cnt += 1
    return cnt


@njit(parallel=True, cache=True)
def _grid_query_kernel(P, h, mask, bucket_start, sorted_ids, sorted_cell, q_lo, q_hi, q_pt,
                       radius, mode, counts, offsets, out, fill):
    """mode 0: point pairs within radius (queries are the grid's points in bucket order, q_pt the
    point ids; only j > i reported). mode 1: points inside closed boxes q_lo/q_hi."""
    nq = q_pt.shape[0] if mode == 0 else q_lo.shape[0]
    nchunks = min(nq, _CHUNKS)
    chunk = (nq + nchunks - 1) // max(nchunks, 1)
    for c in prange(nchunks):
        lo = np.empty(3)
        hi = np.empty(3)
        clo = np.empty(3, dtype=np.int64)
        chi = np.empty(3, dtype=np.int64)
        for k in range(c * chunk, min(nq, (c + 1) * chunk)):
            cnt = _grid_query_one(P, h, mask, bucket_start, sorted_ids, sorted_cell, q_lo, q_hi,
                                  q_pt, radius, mode, k, lo, hi, clo, chi, offsets, out, fill)
            if not fill:
                counts[k] = cnt


def _run_grid_query(grid, P, q_lo, q_hi, q_pt, radius, mode, out):
    nq = q_pt.shape[0] if mode == 0 else q_lo.shape[0]
    if nq == 0 or grid.sorted_ids.shape[0] == 0:
        return _reserve(out, 0)
    counts = np.empty(nq, dtype=np.int64)
    offsets = np.zeros(nq, dtype=np.int64)
    dummy = np.empty((1, 2), dtype=np.int64)
    args = (P, grid.cell_size, grid.mask, grid.bucket_start, grid.sorted_ids, grid.sorted_cell,
            q_lo, q_hi, q_pt, float(radius), mode, counts, offsets)
    _grid_query_kernel(*args, dummy, False)
    np.cumsum(counts[:-1], out=offsets[1:])
    total = int(offsets[-1] + counts[-1])
    pairs = _reserve(out, total)
    if total:
        _grid_query_kernel(*args, pairs, True)
    return pairs


def hash_grid_pairs(grid: HashGrid, P, radius: float, out: PairBuffer | None = None) -> np.ndarray:
    """Point pairs ``(i, j)``, ``i < j``, with ``|P[i] - P[j]|^2 <= radius^2`` (float64 test).

    ``P`` must be the positions the grid was built from. Returns (pair_count, 2) int64.
    """
    P = _as_positions(P, "P")
    if P.shape[0] != grid.sorted_ids.shape[0]:
        raise ValueError(f"hash_grid_pairs: {P.shape[0]} points for a grid of {grid.sorted_ids.shape[0]}")
    r = float(radius)
    if not (r >= 0.0 and np.isfinite(r)):
        raise ValueError(f"radius: must be >= 0 and finite (got {radius})")
    z = np.zeros((0, 3))
    return _run_grid_query(grid, P, z, z, grid.sorted_ids, r, 0, out)


def hash_grid_query_boxes(grid: HashGrid, P, lo, hi, out: PairBuffer | None = None) -> np.ndarray:
    """(box, point) pairs with ``lo[box] <= P[point] <= hi[box]`` on every axis (closed boxes).

    ``P`` must be the positions the grid was built from. Returns (pair_count, 2) int64.
    """
    P = _as_positions(P, "P")
    if P.shape[0] != grid.sorted_ids.shape[0]:
        raise ValueError(f"hash_grid_query_boxes: {P.shape[0]} points for a grid of "
                         f"{grid.sorted_ids.shape[0]}")
    lo, hi = _as_boxes(lo, hi)
    return _run_grid_query(grid, P, lo, hi, np.zeros(0, dtype=np.int64), 0.0, 1, out)


# --------------------------------------------------------------------------------------------
# Sorted column grid: sweep and prune in the columns of a uniform 2-D grid
# --------------------------------------------------------------------------------------------

#: column side of :func:`column_query_self` / :func:`column_query_pairs` over the mean box
#: extent across the two column axes (see ``_col_setup``). 2 instead of 1: fewer entries (a
#: box in 1.9 columns instead of 3.3 on the benchmark's 50k rolled sheet), so fewer repeated
#: tests of a pair in the columns both boxes cross, for more tests of pairs apart on a column
#: axis; the same rows in another order (column by column of another grid; the contacts sort
#: them, ``contacts.GRID_ORDER``). Measured on the 50k rolled sheet's VF + EE queries (1
#: thread, interleaved, CPU): median ratio 0.935 against 1 (34.5 -> 32.3 ms); on the queries
#: recorded from a contact frame (10) of the 64 x 64 drop: 0.986
COLUMN_CELL = 2.0
#: boxes spanning more than this many columns on a column axis are tested against every box
#: (``_col_big_kernel``) instead of being entered into every column they cross
_COL_BIG_SPAN = 4
_COL_NO_ST = np.zeros((0, 14))
#: box counts from which the column count and fill run in chunks on all threads
_COL_PAR_MIN = 16384
#: the column sweep's slots (runs of columns with about equal entry counts), this many a
#: thread, taken by the threads one at a time as they finish (``numba.parallel_chunksize(1)``):
#: the sweep's cost per entry varies over the grid (16 slots of the 50k rolled sheet's edge-edge
#: query, 1 thread: 0.8-4.8 ms; a thread held up by machine load then delays one slot, not
#: half the sweep). The same rows in the same order whatever the slots.
#:
#: Choices measured and kept, whose old paths were dropped (the A/B switches
#: ``COLUMN_GATHERED``, ``COLUMN_DEAL``, ``COLUMN_RADIX``; the rows and their order were the
#: same either way):
#:
#: * the sweep reads int8 flags and every entry's primitive vertices gathered beside its box row
#:   (``_col_gather``, ``_col_body``) for the shared-vertex test, instead of int64 flags and
#:   the primitives' rows at the boxes' numbers (a scattered read per tested pair): the 50k
#:   rolled sheet's VF + EE queries (1 thread, interleaved, CPU) 0.736 (36.1 -> 26.6 ms;
#:   edge-edge 0.650, vertex-face 0.881);
#: * slots dealt one at a time, 8 a thread, instead of one contiguous block of 2 slots a thread
#:   (its wall-time gain was not measured: the machine ran at load 4-6);
#: * the fill order of the boxes from a radix sort instead of ``np.argsort(kind="stable")``,
#:   the same order (the rolled sheet's 75k edge boxes, 1 thread, interleaved: 4.7 against
#:   9.7 ms).
#:
#: With ``COLUMN_CELL`` 1 -> 2 these took the 50k rolled sheet's boxes + VF + EE queries on the
#: idle machine (15 interleaved rounds, same candidate sets) from 48.3 to 35.2 ms at 1 thread
#: and from 31.1 to 24.1 ms wall (53.3 -> 38.4 ms CPU) at 2 threads.
#:
#: Then, each measured against its old path with ``bench broadphase --ab-grid`` (15
#: interleaved rounds, the same rows in the same order; CPU ratio new / old on the shared
#: machine at load 3-5, where the 2-thread wall times are 2-4x the CPU and say little):
#:
#: * the fill order from a parallel bucket sort (``_bucket_order``) instead of the serial radix
#:   sort: the same order; 0.956 at 1 thread, 0.995 at 2 (the sort of the 75k edge boxes
#:   alone, 1 thread: 0.48 against 0.79 ms);
#: * every box's columns packed in one int64 once, in index order (``_col_cells``), for the
#:   count and the fill, which read the boxes in the fill order (at random): 0.936 at 1
#:   thread, 0.899 at 2;
#: * the setup in parallel chunks with the finiteness check (``_col_setup``) instead of a serial
#:   setup after numpy's reductions: 0.959 at 1 thread, 1.016 at 2 (load 5).
#:
#: Tried and dropped: the box rows written in the fill order once and gathered from there
#: (at the count: 1.12x the CPU at 1 thread; in a pass of their own: 1.117x; the boxes of a
#: column are read nearly in order already, neighbours along the sweep axis being neighbours
#: in the mesh); the sweep along another axis than the centres' widest spread (1.57x and
#: 1.37x at 1 thread)
#:
#: Then (``bench broadphase --ab-module`` against d9a0fdc's module, 25 rounds, load 5-6, the
#: same rows in the same order): the setup's mean extents and the sort keys' range in its
#: first pass, the packed columns in the bucket sort's counting pass (two parallel passes over
#: the boxes fewer a query): CPU ratio 0.97-0.98 at 1 thread, 0.97-0.99 at 2.
#: ``COLUMN_SIDE_BY_SIDE`` (``column_queries``, VF and EE side by side) against one after the
#: other at 2 threads, load 5.4-5.9 (``--ab-grid COLUMN_SIDE_BY_SIDE=True``, three runs): 5-10 %
#: less CPU (no spinning at the barriers, no scratch copy), but the wall time went both ways
#: (median per-round wall ratio side by side / one after the other 0.92, 1.14, 1.97: a thread
#: held up by the machine holds up its whole query), so it stays opt-in until measured idle.
COLUMN_SLOTS_PER_THREAD = 8


@njit(parallel=True, cache=True, nogil=True)
def _col_setup(lo, hi, factor, big_span, big, part):
    """Sweep axis, column axes, column side [m], origin and column counts of the sorted column
    grid over boxes ``lo``/``hi``; flags ``big`` (boxes tested against all). The sweep axis is
    the one along which the box centres spread most; the column side starts at ``factor`` x the
    mean box extent over the two other axes and doubles while the grid would have more than
    8 n + 1024 columns or more than n / 256 + 32 big boxes. First whether the boxes are finite
    and spread less than 1e150: else ``ok`` is False and nothing else is set (the caller falls
    back to the trees). In ``part.shape[0]`` chunks of the boxes in parallel, the mean extent
    summed chunk by chunk (a fixed number of chunks: the same grid at any thread count; the
    sums for all three sweep axes in the first pass over the boxes, with the range of the sort
    keys ``lo[:, s] + 0.0``); ``part``: float64 scratch (chunks, ``_COL_SETUP_PART``). Returns
    (ok, s, a0, a1, c, o0, o1, nx, ny, big_count, key_min, key_max)."""
    n = lo.shape[0]
    nch = part.shape[0]
    for k in prange(nch):
        cmin0 = cmin1 = cmin2 = np.inf
        cmax0 = cmax1 = cmax2 = -np.inf
        lmin = hmin = np.inf
        lmax = hmax = -np.inf
        kmin0 = kmin1 = kmin2 = np.inf
        kmax0 = kmax1 = kmax2 = -np.inf
        e0 = e1 = e2 = 0.0
        bad = 0.0
        for i in range(k * n // nch, (k + 1) * n // nch):
            # x - x is 0 for a finite x, NaN for an infinite or NaN one
            bad += ((lo[i, 0] - lo[i, 0]) + (lo[i, 1] - lo[i, 1]) + (lo[i, 2] - lo[i, 2])
                    + (hi[i, 0] - hi[i, 0]) + (hi[i, 1] - hi[i, 1]) + (hi[i, 2] - hi[i, 2]))
            lmin = min(lmin, lo[i, 0], lo[i, 1], lo[i, 2])
            lmax = max(lmax, lo[i, 0], lo[i, 1], lo[i, 2])
            hmin = min(hmin, hi[i, 0], hi[i, 1], hi[i, 2])
            hmax = max(hmax, hi[i, 0], hi[i, 1], hi[i, 2])
            m0 = 0.5 * lo[i, 0] + 0.5 * hi[i, 0]
            m1 = 0.5 * lo[i, 1] + 0.5 * hi[i, 1]
            m2 = 0.5 * lo[i, 2] + 0.5 * hi[i, 2]
            cmin0 = min(cmin0, m0)
            cmax0 = max(cmax0, m0)
            cmin1 = min(cmin1, m1)
            cmax1 = max(cmax1, m1)
            cmin2 = min(cmin2, m2)
            cmax2 = max(cmax2, m2)
            # the mean extent over the two column axes, for each sweep axis s (a0, a1 below)
            d0 = hi[i, 0] - lo[i, 0]
            d1 = hi[i, 1] - lo[i, 1]
            d2 = hi[i, 2] - lo[i, 2]
            e0 += max(d1, d2)
            e1 += max(d0, d2)
            e2 += max(d0, d1)
            # the range of the sort keys lo[:, s] + 0.0 (_bucket_order)
            k0 = lo[i, 0] + 0.0
            k1 = lo[i, 1] + 0.0
            k2 = lo[i, 2] + 0.0
            kmin0 = min(kmin0, k0)
            kmax0 = max(kmax0, k0)
            kmin1 = min(kmin1, k1)
            kmax1 = max(kmax1, k1)
            kmin2 = min(kmin2, k2)
            kmax2 = max(kmax2, k2)
        part[k, 0] = cmin0
        part[k, 1] = cmin1
        part[k, 2] = cmin2
        part[k, 3] = cmax0
        part[k, 4] = cmax1
        part[k, 5] = cmax2
        part[k, 6] = lmin
        part[k, 7] = lmax
        part[k, 8] = hmin
        part[k, 9] = hmax
        part[k, 10] = e0
        part[k, 11] = e1
        part[k, 12] = e2
        part[k, 13] = kmin0
        part[k, 14] = kmin1
        part[k, 15] = kmin2
        part[k, 16] = kmax0
        part[k, 17] = kmax1
        part[k, 18] = kmax2
        if bad != 0.0:
            part[k, 6] = np.nan
    cmin = np.full(3, np.inf)
    cmax = np.full(3, -np.inf)
    lmin = hmin = np.inf
    lmax = hmax = -np.inf
    ok = True
    for k in range(nch):
        if part[k, 6] != part[k, 6]:
            ok = False
        for a in range(3):
            cmin[a] = min(cmin[a], part[k, a])
            cmax[a] = max(cmax[a], part[k, 3 + a])
        lmin = min(lmin, part[k, 6])
        lmax = max(lmax, part[k, 7])
        hmin = min(hmin, part[k, 8])
        hmax = max(hmax, part[k, 9])
    span = max(hmax - lmin, lmax - hmin)
    if not (ok and np.isfinite(span) and span < 1e150):
        return False, 0, 0, 0, 0.0, 0.0, 0.0, 0, 0, 0, 0.0, 0.0
    s = 0
    for a in range(1, 3):
        if cmax[a] - cmin[a] > cmax[s] - cmin[s]:
            s = a
    a0 = 1 if s == 0 else 0
    a1 = 1 if s == 2 else 2
    ext = 0.0
    kmin = np.inf
    kmax = -np.inf
    for k in range(nch):
        ext += part[k, 10 + s]
        kmin = min(kmin, part[k, 13 + s])
        kmax = max(kmax, part[k, 16 + s])
    c = factor * ext / max(n, 1)
    span = max(cmax[a0] - cmin[a0], cmax[a1] - cmin[a1])
    if not c > 0.0:
        c = span / np.sqrt(max(n, 1)) if span > 0.0 else 1.0
    if not c > 0.0:
        c = 1.0
    while True:
        lim = big_span * c
        for k in prange(nch):
            nb = 0
            q0 = q1 = np.inf
            f0 = f1 = -np.inf
            for i in range(k * n // nch, (k + 1) * n // nch):
                bg = hi[i, a0] - lo[i, a0] > lim or hi[i, a1] - lo[i, a1] > lim
                big[i] = bg
                if bg:
                    nb += 1
                else:
                    q0 = min(q0, lo[i, a0])
                    q1 = min(q1, lo[i, a1])
                    f0 = max(f0, hi[i, a0])
                    f1 = max(f1, hi[i, a1])
            part[k, 0] = nb
            part[k, 1] = q0
            part[k, 2] = q1
            part[k, 3] = f0
            part[k, 4] = f1
        nbig = 0
        o0 = o1 = np.inf
        e0 = e1 = -np.inf
        for k in range(nch):
            nbig += int(part[k, 0])
            o0 = min(o0, part[k, 1])
            o1 = min(o1, part[k, 2])
            e0 = max(e0, part[k, 3])
            e1 = max(e1, part[k, 4])
        if nbig == n:
            return True, s, a0, a1, c, 0.0, 0.0, 1, 1, nbig, kmin, kmax
        nx = int((e0 - o0) / c) + 1
        ny = int((e1 - o1) / c) + 1
        if (nx * ny <= 8 * n + 1024 and nbig <= n // 256 + 32) or not np.isfinite(c * 2.0):
            return True, s, a0, a1, c, o0, o1, nx, ny, nbig, kmin, kmax
        c *= 2.0


_COL_SETUP_CHUNKS = 64  # chunks of _col_setup (fixed: the same grid at any thread count)
_COL_SETUP_PART = 19  # its per-chunk partial results


@njit(inline="always", cache=True)
def _cells(lo, hi, i, a0, a1, c, o0, o1):
    """The grid columns box ``i`` covers: x0..x1 along ``a0``, y0..y1 along ``a1`` (cell ``c``,
    origin ``o0``, ``o1``)."""
    return (int((lo[i, a0] - o0) / c), int((hi[i, a0] - o0) / c),
            int((lo[i, a1] - o1) / c), int((hi[i, a1] - o1) / c))


@njit(inline="always", cache=True)
def _cell_code(lo, hi, big, i, a0, a1, c, o0, o1, ny):
    """Box ``i``'s columns packed in one int64 (:func:`_col_cells`), -1 for a big box."""
    if big[i]:
        return -1
    x0, x1, y0, y1 = _cells(lo, hi, i, a0, a1, c, o0, o1)
    return ((x0 * ny + y0) << 8) | ((x1 - x0) << 4) | (y1 - y0)


@njit(cache=True, inline="always")
def _bucket(v, vmin, scale, nb):
    """The bucket of ``v`` among ``nb`` (non-decreasing in ``v``: every step rounds
    monotonically; overflow or a zero scale ends in the first or the last)."""
    t = (v - vmin) * scale
    return int(t) if t < nb else nb - 1


@njit(parallel=True, cache=True, nogil=True)
def _bucket_order(lo, s, vmin, vmax, order, key, key2, hist, bstart, width, hi, big, a0, a1, c,
                  o0, o1, ny, cells):
    """``order``: the boxes ``0 .. n-1`` by ``lo[:, s]`` (-0.0 equal to 0.0), ties by index:
    ``np.argsort(lo[:, s], kind="stable")``, in parallel; ``vmin``, ``vmax``: the least and
    greatest of ``lo[:, s] + 0.0``. The values go into ``nb = bstart.shape[0] - 1`` buckets of
    equal width between them (a counting sort, ``hist.shape[0]`` chunks of the boxes in
    parallel, each chunk's boxes in index order), then every bucket is sorted on its own
    (insertion, stable; past ``width`` shifts a value on average: a merge sort). ``key``,
    ``key2``: float64 scratch of n; ``hist``: int64 (chunks, nb). With ``cells`` of n entries
    (else empty), every box's packed columns (:func:`_col_cells`) in the pass that counts the
    buckets."""
    n = lo.shape[0]
    nch = hist.shape[0]
    nb = bstart.shape[0] - 1
    with_cells = cells.shape[0] > 0
    scale = nb / (vmax - vmin) if vmax > vmin else 0.0
    for k in prange(nch):
        hist[k, :] = 0
        for i in range(k * n // nch, (k + 1) * n // nch):
            v = lo[i, s] + 0.0
            key[i] = v
            hist[k, _bucket(v, vmin, scale, nb)] += 1
            if with_cells:
                cells[i] = _cell_code(lo, hi, big, i, a0, a1, c, o0, o1, ny)
    pos = 0
    for j in range(nb):
        bstart[j] = pos
        for k in range(nch):
            c_ = hist[k, j]
            hist[k, j] = pos
            pos += c_
    bstart[nb] = pos
    for k in prange(nch):
        for i in range(k * n // nch, (k + 1) * n // nch):
            v = key[i]
            j = _bucket(v, vmin, scale, nb)
            p = hist[k, j]
            hist[k, j] = p + 1
            order[p] = i
            key2[p] = v
    nsort = 8 * nch if nch > 1 else 1
    for t in prange(nsort):
        for j in range(t * nb // nsort, (t + 1) * nb // nsort):
            s0 = bstart[j]
            e = bstart[j + 1]
            budget = width * (e - s0)  # shifts; past them the rest is merge sorted
            for p in range(s0 + 1, e):
                v = key2[p]
                if not key2[p - 1] > v:
                    continue
                i = order[p]
                q = p - 1
                while q >= s0 and key2[q] > v:
                    key2[q + 1] = key2[q]
                    order[q + 1] = order[q]
                    q -= 1
                key2[q + 1] = v
                order[q + 1] = i
                budget -= p - 1 - q
                if budget < 0:
                    # stable: the insertion sort kept equal values in index order
                    perm = np.argsort(key2[s0:e], kind="mergesort")
                    idx = order[s0:e].copy()
                    for r in range(e - s0):
                        order[s0 + r] = idx[perm[r]]
                    break


_BUCKET_SIZE = 8  # mean values per bucket of _bucket_order
_BUCKET_WIDTH = 8  # mean shifts a value of a bucket's insertion sort before a merge sort


_NO_CELLS = np.zeros(0, np.int64)
_NO_BIG = np.zeros(0, np.bool_)


def _sweep_order(lo, s, out, vmin=None, vmax=None, cells=None):
    """The boxes by their low end on the sweep axis ``s``, ties by index: ``np.argsort(kind=
    "stable")``, from :func:`_bucket_order` from 256 boxes on (in parallel from
    ``_COL_PAR_MIN``). ``vmin``, ``vmax``: the range of ``lo[:, s] + 0.0`` if known. ``cells``:
    ``(hi, big, a0, a1, c, o0, o1, ny, cells)``, the packed columns to fill in the same pass
    (:func:`_col_cells`; in any case, also under 256 boxes)."""
    n = lo.shape[0]
    if n < 256:
        if cells is not None:
            hi, big, a0, a1, c, o0, o1, ny, cl = cells
            _col_cells(lo, hi, big, a0, a1, c, o0, o1, ny, cl)
        return np.argsort(lo[:, s], kind="stable")
    if vmin is None:
        key = lo[:, s] + 0.0
        vmin, vmax = float(key.min()), float(key.max())
    if cells is None:
        cells = (lo, _NO_BIG, 0, 0, 1.0, 0.0, 0.0, 1, _NO_CELLS)
    order = _col_work(out, "sort_o", (n,), np.int64)
    nch = get_num_threads() if n >= _COL_PAR_MIN else 1
    nb = max(1, n // _BUCKET_SIZE)
    _bucket_order(lo, s, vmin, vmax, order, _col_work(out, "sort_v", (n,)),
                  _col_work(out, "sort_v2", (n,)), _col_work(out, "sort_h", (nch, nb), np.int64),
                  _col_work(out, "sort_b", (nb + 1,), np.int64), _BUCKET_WIDTH, *cells)
    return order


@njit(cache=True, nogil=True)
def _col_offsets(hist, start, mid):
    """CSR offsets from the chunks' counts: column ``col`` holds set a's entries (chunk 0,
    1, ...) then set b's from ``mid[col]``; ``hist`` becomes every chunk's first position per
    set and column. Returns the entry count."""
    nch = hist.shape[0]
    ncol = hist.shape[2]
    pos = 0
    for col in range(ncol):
        start[col] = pos
        for b in range(2):
            if b == 1:
                mid[col] = pos
            for k in range(nch):
                cnt = hist[k, b, col]
                hist[k, b, col] = pos
                pos += cnt
    start[ncol] = pos
    return pos


@njit(cache=True, inline="always")
def _st_keep(st, ia, ib):
    """The space-time tests of a pair (rows ``ia``, ``ib`` of ``st``, not empty): not two inactive
    primitives, space-time overlap within one group."""
    if st[ia, 12] == 0.0 and st[ib, 12] == 0.0:
        return False
    return not (st[ia, 13] == st[ib, 13] and not _st_overlap(st, ia, st, ib))


@njit(cache=True, inline="always")
def _col_keep(pa, pb, ia, ib, prims_a, prims_b, skip_shared, st):
    """The leaf tests of ``_ovl`` after the box overlap, for primitives pa (set a) and pb (set
    b), rows ia, ib of ``st``: not two inactive primitives, space-time overlap within one group,
    no shared vertex."""
    if st.shape[0] and not _st_keep(st, ia, ib):
        return False
    return not (skip_shared and _share_vertex(prims_a, pa, prims_b, pb))


@njit(parallel=True, cache=True, nogil=True)
def _col_cells(lo, hi, big, a0, a1, c, o0, o1, ny, cells):
    """Every box's columns packed in one int64: its first column
    ``x0 * ny + y0`` above 8 bits, ``x1 - x0`` in bits 4-7, ``y1 - y0`` in bits 0-3 (a box that
    is not big spans at most ``_COL_BIG_SPAN`` + 1 columns an axis); -1 for a big box. The
    count and the fill read these 8 bytes a box in the fill order instead of its two box rows."""
    for i in prange(lo.shape[0]):
        cells[i] = _cell_code(lo, hi, big, i, a0, a1, c, o0, o1, ny)


@njit(cache=True, nogil=True)
def _col_count(cells, na, ny, start, mid):
    """CSR offsets ``start`` (ncol + 1) of the boxes' column entries (packed columns
    ``cells``, :func:`_col_cells`), a column's entries of set a (boxes ``0 .. na-1``) first,
    those of set b from ``mid[col]`` on; returns their number."""
    ncol = start.shape[0] - 1
    start[:] = 0
    mid[:] = 0
    for i in range(cells.shape[0]):
        v = cells[i]
        if v < 0:
            continue
        col0 = v >> 8
        dx = (v >> 4) & 15
        dy = v & 15
        for x in range(dx + 1):
            for y in range(dy + 1):
                start[col0 + x * ny + y + 1] += 1
                if i < na:
                    mid[col0 + x * ny + y] += 1
    for k in range(ncol):
        start[k + 1] += start[k]
        mid[k] += start[k]
    return start[ncol]


@njit(parallel=True, cache=True, nogil=True)
def _col_hist(cells, order, na, ny, hist):
    """Parallel column count: chunk k of ``order`` (``hist.shape[0]`` equal chunks) counts its
    boxes' entries per column (packed columns ``cells``) into ``hist[k, 0]`` (set a) and
    ``hist[k, 1]`` (set b)."""
    nch = hist.shape[0]
    m = order.shape[0]
    for k in prange(nch):
        hist[k, :, :] = 0
        for t in range(k * m // nch, (k + 1) * m // nch):
            i = order[t]
            v = cells[i]
            if v < 0:
                continue
            col0 = v >> 8
            dx = (v >> 4) & 15
            dy = v & 15
            b = 0 if i < na else 1
            for x in range(dx + 1):
                for y in range(dy + 1):
                    hist[k, b, col0 + x * ny + y] += 1


@njit(parallel=True, cache=True, nogil=True)
def _col_fill(cells, order, na, ny, hist, ent, flag):
    """Counting sort of the boxes' column entries (packed columns ``cells``) in ``order`` (by
    the low end on the sweep axis, so both sets' runs of every column are sorted), chunk k of
    ``order`` (``hist.shape[0]`` chunks, in parallel) from its positions ``hist[k]`` (of
    :func:`_col_offsets`; one chunk: the columns' first positions); ``flag``: bit 0 set where
    the column is the box's first along a0, bit 1 along a1."""
    nch = hist.shape[0]
    m = order.shape[0]
    for k in prange(nch):
        for t in range(k * m // nch, (k + 1) * m // nch):
            i = order[t]
            v = cells[i]
            if v < 0:
                continue
            col0 = v >> 8
            dx = (v >> 4) & 15
            dy = v & 15
            b = 0 if i < na else 1
            for x in range(dx + 1):
                for y in range(dy + 1):
                    col = col0 + x * ny + y
                    p = hist[k, b, col]
                    hist[k, b, col] = p + 1
                    ent[p] = i
                    flag[p] = (1 if x == 0 else 0) | (2 if y == 0 else 0)


@njit(parallel=True, cache=True, nogil=True)
def _col_gather(ent, lo, hi, s, a0, a1, na, prims_a, prims_b, skip_shared, B, V):
    """The entries' box rows ``B[p]`` (sweep axis, column axes a0, a1: low, high each) and,
    with ``skip_shared``, their primitive vertices ``V[p]`` for the shared-vertex test, the
    unused places ``-1 - box`` (equal to no vertex and to no other box's)."""
    w = V.shape[1]
    for p in prange(ent.shape[0]):
        i = ent[p]
        B[p, 0] = lo[i, s]
        B[p, 1] = hi[i, s]
        B[p, 2] = lo[i, a0]
        B[p, 3] = hi[i, a0]
        B[p, 4] = lo[i, a1]
        B[p, 5] = hi[i, a1]
        if skip_shared:
            for x in range(w):
                V[p, x] = -1 - i
            if i < na:
                for x in range(prims_a.shape[1]):
                    V[p, x] = prims_a[i, x]
            else:
                for x in range(prims_b.shape[1]):
                    V[p, x] = prims_b[i - na, x]


@njit(cache=True, inline="always")
def _share_v(V, p, q):
    if V.shape[1] == 3:  # branch-free, the usual width (narrower primitives padded to 3)
        v0, v1, v2 = V[p, 0], V[p, 1], V[p, 2]
        w0, w1, w2 = V[q, 0], V[q, 1], V[q, 2]
        return ((v0 == w0) | (v0 == w1) | (v0 == w2) | (v1 == w0) | (v1 == w1) | (v1 == w2)
                | (v2 == w0) | (v2 == w1) | (v2 == w2))
    for x in range(V.shape[1]):
        v = V[p, x]
        for y in range(V.shape[1]):
            if v == V[q, y]:
                return True
    return False


@njit(cache=True, nogil=True)
def _col_body(B, flag, ent, V, s0, m, e1, na, self_mode, skip_shared, st, out, pos, lim):
    """Sweep one column: entries ``s0 .. e1-1`` (self mode), or those of set a ``s0 .. m-1``
    against those of set b ``m .. e1-1`` (each pair once: from its entry with the lower low end
    on the sweep axis, ties from the set-a entry). A pair needs overlapping boxes on the two
    column axes and is kept only in the column of its overlap's low corner (one of its entries
    is its box's first column on each axis: ``flag``), then no shared vertex (the gathered
    vertices ``V``) and the space-time tests (``_st_keep``). Rows go to ``out`` from ``pos``
    while below ``lim``; returns the pair count."""
    cnt = 0
    has_st = st.shape[0] > 0
    if self_mode:
        for p in range(s0, e1):
            his = B[p, 1]
            l0 = B[p, 2]
            h0 = B[p, 3]
            l1 = B[p, 4]
            h1 = B[p, 5]
            need = 3 ^ flag[p]
            i = ent[p]
            for q in range(p + 1, e1):
                if B[q, 0] > his:
                    break
                if (flag[q] & need) != need:
                    continue
                if (B[q, 2] > h0) | (B[q, 3] < l0) | (B[q, 4] > h1) | (B[q, 5] < l1):
                    continue
                if skip_shared and _share_v(V, p, q):
                    continue
                j = ent[q]
                pa = min(i, j)
                pb = max(i, j)
                if has_st and not _st_keep(st, pa, pb):
                    continue
                if pos < lim:
                    out[pos, 0] = pa
                    out[pos, 1] = pb
                pos += 1
                cnt += 1
        return cnt
    for side in range(2):
        f0 = s0 if side == 0 else m
        f1 = m if side == 0 else e1
        g0 = m if side == 0 else s0
        g1 = e1 if side == 0 else m
        q0 = g0
        for p in range(f0, f1):
            los = B[p, 0]
            if side == 0:
                while q0 < g1 and B[q0, 0] < los:
                    q0 += 1
            else:
                while q0 < g1 and B[q0, 0] <= los:
                    q0 += 1
            his = B[p, 1]
            l0 = B[p, 2]
            h0 = B[p, 3]
            l1 = B[p, 4]
            h1 = B[p, 5]
            need = 3 ^ flag[p]
            i = ent[p]
            for q in range(q0, g1):
                if B[q, 0] > his:
                    break
                if (flag[q] & need) != need:
                    continue
                if (B[q, 2] > h0) | (B[q, 3] < l0) | (B[q, 4] > h1) | (B[q, 5] < l1):
                    continue
                if skip_shared and _share_v(V, p, q):
                    continue
                j = ent[q]
                ia = i if side == 0 else j
                ib = j if side == 0 else i
                if has_st and not _st_keep(st, ia, ib):
                    continue
                if pos < lim:
                    out[pos, 0] = ia
                    out[pos, 1] = ib - na
                pos += 1
                cnt += 1
    return cnt


@njit(parallel=True, cache=True, nogil=True)
def _col_slots(B, flag, ent, V, start, mid, na, self_mode, skip_shared, st, slots, slot_col,
                 slot_pos, slot_lim, out, slot_cnt):
    """Sweep the columns of every slot in ``slots`` (slot k: columns ``slot_col[k] ..
    slot_col[k+1]-1`` in order), writing its rows from ``slot_pos[k]`` while below
    ``slot_lim[k]``; ``slot_cnt[k]``: its pair count (also when they did not fit)."""
    for t in prange(slots.shape[0]):
        k = slots[t]
        pos = slot_pos[k]
        for col in range(slot_col[k], slot_col[k + 1]):
            pos += _col_body(B, flag, ent, V, start[col], mid[col], start[col + 1], na,
                               self_mode, skip_shared, st, out, pos, slot_lim[k])
        slot_cnt[k] = pos - slot_pos[k]


@njit(parallel=True, cache=True, nogil=True)
def _col_copy(src, src_pos, dst, dst_pos, cnt, done):
    for k in prange(cnt.shape[0]):
        if not done[k]:
            continue
        for r in range(cnt[k]):
            dst[dst_pos[k] + r, 0] = src[src_pos[k] + r, 0]
            dst[dst_pos[k] + r, 1] = src[src_pos[k] + r, 1]


@njit(parallel=True, cache=True, nogil=True)
def _col_big_kernel(lo, hi, bigs, big, na, self_mode, prims_a, prims_b, skip_shared, st,
                    counts, offsets, out, fill):
    """Every big box against every box of the other set (self mode: every other box), a pair of
    two big boxes once (from the smaller index)."""
    n = lo.shape[0]
    for t in prange(bigs.shape[0]):
        i = bigs[t]
        cnt = 0
        pos = offsets[t] if fill else 0
        for j in range(n):
            if j == i or (big[j] and j < i) or (not self_mode and (i < na) == (j < na)):
                continue
            if not _overlap(lo, hi, i, lo, hi, j):
                continue
            ia = min(i, j) if self_mode or i < na else j
            ib = max(i, j) if self_mode or i < na else i
            pb = ib if self_mode else ib - na
            if not _col_keep(ia, pb, ia, ib, prims_a, prims_b, skip_shared, st):
                continue
            if fill:
                out[pos, 0] = ia
                out[pos, 1] = pb
                pos += 1
            cnt += 1
        if not fill:
            counts[t] = cnt


def _tree_fallback(lo, hi, na, self_mode, prims_a, prims_b, skip_shared, st, out):
    """The tree queries on the same boxes (non-finite or astronomically spread coordinates,
    where the column indices would overflow)."""
    def tree(lo_, hi_, st_):
        t = build_bvh(lo_, hi_)
        if st_.shape[0] == 0:
            return t, _NO_ST
        node_st = np.empty((2 * lo_.shape[0] - 1, 14))
        _st_refit(np.ascontiguousarray(st_), t.leaf_prim, t.child, t.refit_order, node_st)
        return t, node_st
    if self_mode:
        t, nst = tree(lo, hi, st)
        return _run_tt(t, t, prims_a, prims_a, skip_shared, True, out,
                       nst if st.shape[0] else None, nst if st.shape[0] else None)
    ta, sa = tree(lo[:na], hi[:na], st[:na])
    tb, sb = tree(lo[na:], hi[na:], st[na:])
    return _run_tt(ta, tb, prims_a, prims_b, skip_shared, False, out,
                   sa if st.shape[0] else None, sb if st.shape[0] else None)


def _col_work(out, key, shape, dtype=np.float64):
    """A scratch array of ``shape`` kept in the buffer ``out`` under ``key``: a flat buffer
    grown by half when too small, returned as a C-contiguous view of its first elements in the
    shape asked (any of its dimensions may change between calls), or a new array without a
    buffer."""
    if out is None:
        return np.empty(shape, dtype=dtype)
    ws = out.__dict__.setdefault("_col_ws", {})
    a = ws.get(key)
    size = 1
    for d in shape:
        size *= int(d)
    if a is None or a.shape[0] < size:
        a = ws[key] = np.empty(grown_size(size, a.shape[0] if a is not None else 0),
                               dtype=dtype)
    return a[:size].reshape(shape)


def _dealt(nslot):
    """The parallel chunk size of the column sweep's slots: one slot at a time."""
    if nslot > 1:
        return parallel_chunksize(1)
    return contextlib.nullcontext()


def _run_columns(lo, hi, na, self_mode, prims_a, prims_b, skip_shared, st, out):
    n = lo.shape[0]
    if n == 0:
        return _reserve(out, 0)
    big = _col_work(out, "big", (n,), np.bool_)
    ok, s, a0, a1, c, o0, o1, nx, ny, nbig, kmin, kmax = _col_setup(
        lo, hi, COLUMN_CELL, _COL_BIG_SPAN, big,
        _col_work(out, "part", (_COL_SETUP_CHUNKS, _COL_SETUP_PART)))
    if not ok:
        return _tree_fallback(lo, hi, na, self_mode, prims_a, prims_b, skip_shared, st, out)
    ncol = nx * ny
    start = _col_work(out, "start", (ncol + 1,), np.int64)
    mid = _col_work(out, "mid", (ncol,), np.int64)
    nch = get_num_threads() if n >= _COL_PAR_MIN else 1
    w = max(prims_a.shape[1], prims_b.shape[1], 3)
    cells = _col_work(out, "cells", (n,), np.int64)
    hist = _col_work(out, "hist", (nch, 2, ncol), np.int64)
    # the fill order, and every box's packed columns in the same pass over the boxes
    order = _sweep_order(lo, s, out, kmin, kmax, (hi, big, a0, a1, c, o0, o1, ny, cells))
    if nch > 1:
        # the counting sort in chunks, in parallel (same entries in the same order)
        _col_hist(cells, order, na, ny, hist)
        nent = _col_offsets(hist, start, mid)
    else:
        nent = _col_count(cells, na, ny, start, mid)
        hist[0, 0] = start[:-1]
        hist[0, 1] = mid
    ent = _col_work(out, "ent", (nent,), np.int64)
    flag = _col_work(out, "flag8", (nent,), np.int8)
    if nent:
        _col_fill(cells, order, na, ny, hist, ent, flag)
    B = _col_work(out, "B", (nent, 6))
    V = _col_work(out, "V", (nent, w) if skip_shared else (1, w), np.int64)
    _col_gather(ent, lo, hi, s, a0, a1, na, prims_a, prims_b, skip_shared, B, V)
    args = (B, flag, ent, V, start, mid, na, self_mode, skip_shared, st)
    sweep = _col_slots
    # slots: runs of whole columns with about equal entry counts, dealt to the threads one at a
    # time; the rows come in column order whatever the slots
    nth = get_num_threads()
    nslot = max(1, min(_SLOTS, ncol, COLUMN_SLOTS_PER_THREAD * nth))
    if nth == 1:
        nslot = 1
    slot_col = np.searchsorted(start, (nent * np.arange(nslot + 1)) // nslot).astype(np.int64)
    slot_col[0] = 0
    slot_col[-1] = ncol
    slots = np.arange(nslot, dtype=np.int64)
    cnt = np.zeros(nslot, dtype=np.int64)
    expected = out.expected if out is not None else 0
    if expected > 0:
        # one sweep into scratch sized from this buffer's previous query (2x, as the trees';
        # one slot: into the output itself); only slots that overflow are swept again
        cap = (2 * expected) // nslot + 64 if nslot > 1 else 2 * expected + 1024
        buf = out.scratch_rows(nslot * cap) if nslot > 1 else out.reserve(cap)
        pos = cap * slots
        with _dealt(nslot):
            sweep(*args, slots, slot_col, pos, pos + cap, buf, cnt)
    else:
        pos = np.zeros(nslot, dtype=np.int64)
        with _dealt(nslot):
            sweep(*args, slots, slot_col, pos, pos, _DUMMY, cnt)  # count pass
        cap = -1
        buf = _DUMMY
    offsets = np.zeros(nslot, dtype=np.int64)
    np.cumsum(cnt[:-1], out=offsets[1:])
    total = int(offsets[-1] + cnt[-1])
    bigs = np.flatnonzero(big).astype(np.int64)
    bargs = (lo, hi, bigs, big, na, self_mode, prims_a, prims_b, skip_shared, st)
    btotal = 0
    if len(bigs):
        bcounts = np.empty(len(bigs), dtype=np.int64)
        boffsets = np.zeros(len(bigs), dtype=np.int64)
        _col_big_kernel(*bargs, bcounts, boffsets, _DUMMY, False)
        np.cumsum(bcounts[:-1], out=boffsets[1:])
        btotal = int(boffsets[-1] + bcounts[-1])
    fits = cnt <= cap
    if nslot == 1 and cap >= 0:
        if fits[0] and btotal:
            buf = buf[:total].copy()  # the output grows for the big boxes' rows
        pairs = _reserve(out, total + btotal)
        if fits[0] and btotal:
            pairs[:total] = buf
    else:
        pairs = _reserve(out, total + btotal)
        if cap >= 0:
            _col_copy(buf, pos, pairs, offsets, cnt, fits)
    redo = np.flatnonzero(~fits).astype(np.int64)
    if len(redo):
        sweep(*args, redo, slot_col, offsets, offsets + cnt, pairs, np.empty(nslot, np.int64))
    if btotal:
        _col_big_kernel(*bargs, bcounts, boffsets, pairs[total:], True)
    if out is not None:
        out.expected = max(total, 1)
    return pairs


def spacetime_prim_boxes(X0, prims, X1, thickness=0.0, active=None, group=None,
                         out=None) -> np.ndarray:
    """The rows of :func:`spacetime_boxes` for the primitives themselves, in primitive order,
    shape (m, 14) (the ``st`` arguments of :func:`column_query_self` /
    :func:`column_query_pairs`)."""
    X0 = _as_positions(X0, "X0")
    X1 = _as_positions(X1, "X1")
    P = _as_prims(prims)
    t = np.asarray(thickness, dtype=np.float64)
    per_vertex = t.ndim > 0
    t = np.ascontiguousarray(t.reshape(-1))
    m = P.shape[0]
    act = np.zeros(0, np.bool_) if active is None else np.ascontiguousarray(active, np.bool_)
    if act.shape[0] not in (0, m):
        raise ValueError(f"active: expected shape ({m},), got {act.shape}")
    grp = np.zeros(0, np.int64) if group is None else np.ascontiguousarray(group, np.int64)
    if grp.shape[0] not in (0, m) or (grp.shape[0] and grp.min() < 0):
        raise ValueError(f"group: expected shape ({m},) of ints >= 0")
    st = np.empty((m, 14)) if out is None else out
    if m:
        _st_prim_kernel(X0, X1, P, t, per_vertex, act, grp, st)
    return st


def column_query_self(lo, hi, prims=None, out: PairBuffer | None = None, st=None) -> np.ndarray:
    """:func:`query_self` without a tree: the same candidate pairs (rows ``(i, j)``, ``i < j``)
    from a sorted column grid over the boxes ``lo``, ``hi``; ``st``: the primitives'
    :func:`spacetime_prim_boxes`. The rows come column by column (deterministic, independent of
    the thread count), in another order than the tree query's."""
    lo, hi = _as_boxes(lo, hi)
    m = lo.shape[0]
    if prims is None:
        P, skip = _empty_prims(), False
    else:
        P, skip = _as_prims(prims), True
        if P.shape[0] != m:
            raise ValueError(f"column_query_self: {P.shape[0]} primitives for {m} boxes")
    st = _COL_NO_ST if st is None else np.ascontiguousarray(st, dtype=np.float64)
    if st.shape[0] not in (0, m):
        raise ValueError("st: expected the spacetime_prim_boxes of the primitives")
    return _run_columns(lo, hi, m, True, P, P, skip, st, out)


def column_query_pairs(lo_a, hi_a, lo_b, hi_b, prims_a=None, prims_b=None,
                       out: PairBuffer | None = None, st_a=None, st_b=None) -> np.ndarray:
    """:func:`query_pairs` without trees: the same rows ``(prim_a, prim_b)`` from a sorted column
    grid over both box sets (``st_a``, ``st_b``: the primitives' :func:`spacetime_prim_boxes`),
    column by column."""
    lo_a, hi_a = _as_boxes(lo_a, hi_a)
    lo_b, hi_b = _as_boxes(lo_b, hi_b)
    if (prims_a is None) != (prims_b is None):
        raise ValueError("column_query_pairs: give both prims_a and prims_b, or neither")
    na, nb = lo_a.shape[0], lo_b.shape[0]
    if prims_a is None:
        Pa = Pb = _empty_prims()
        skip = False
    else:
        Pa, Pb, skip = _as_prims(prims_a, "prims_a"), _as_prims(prims_b, "prims_b"), True
        if Pa.shape[0] != na or Pb.shape[0] != nb:
            raise ValueError("column_query_pairs: prims_a/prims_b sizes differ from the box counts")
    if na == 0 or nb == 0:
        return _reserve(out, 0)
    if (st_a is None) != (st_b is None):
        raise ValueError("column_query_pairs: give both st_a and st_b, or neither")
    if st_a is None:
        st = _COL_NO_ST
    else:
        if st_a.shape[0] != na or st_b.shape[0] != nb:
            raise ValueError("st: expected the spacetime_prim_boxes of the primitives")
        st = _col_work(out, "st", (na + nb, 14))
        st[:na] = st_a
        st[na:] = st_b
    lo = _col_work(out, "lo", (na + nb, 3))
    hi = _col_work(out, "hi", (na + nb, 3))
    lo[:na] = lo_a
    lo[na:] = lo_b
    hi[:na] = hi_a
    hi[na:] = hi_b
    return _run_columns(lo, hi, na, False, Pa, Pb, skip, st, out)


#: :func:`column_queries` runs its queries side by side, each on one thread with one numba
#: thread, when numba has at least two threads and every query has at least
#: ``_COL_SIDE_MIN`` boxes; else one after another, each on all threads. False: always one
#: after another. The rows and their order are the same either way.
COLUMN_SIDE_BY_SIDE = False
_COL_SIDE_MIN = 4096
_SIDE_POOL = []  # the worker threads of column_queries (a ThreadPoolExecutor, made once)


def _side_pool(workers: int):
    if not _SIDE_POOL or _SIDE_POOL[0]._max_workers < workers:
        from concurrent.futures import ThreadPoolExecutor

        if _SIDE_POOL:
            _SIDE_POOL.pop().shutdown(wait=False)
        _SIDE_POOL.append(ThreadPoolExecutor(max_workers=workers,
                                             thread_name_prefix="broadphase-side"))
    return _SIDE_POOL[0]


def _one_thread(fn, args, kwargs):
    """``fn(*args, **kwargs)`` with one numba thread on this thread (numba's thread count is
    per thread), restored after."""
    from numba import set_num_threads

    keep = get_num_threads()
    set_num_threads(1)
    try:
        return fn(*args, **kwargs)
    finally:
        set_num_threads(keep)


def column_queries(*queries) -> list:
    """Several column-grid queries, each ``(fn, args, kwargs)`` with ``fn``
    :func:`column_query_pairs` or :func:`column_query_self` (distinct ``out`` buffers), run
    side by side (``COLUMN_SIDE_BY_SIDE``): each query on its own thread with one numba thread,
    its kernels releasing the GIL, so the queries' stages run without a barrier between the
    threads and each sweep writes its rows straight into its output (one slot, no scratch
    copy). Returns their results in order: the same rows in the same order as the calls one
    after another (the column grid's rows do not depend on the thread count). With one numba
    thread, or a query under ``_COL_SIDE_MIN`` boxes: the calls one after another.

    Measured on the 50k rolled sheet's VF + EE (``bench broadphase``): see the module
    docstring."""
    nth = get_num_threads()
    if (not COLUMN_SIDE_BY_SIDE or nth < 2 or len(queries) < 2
            or min(_query_size(q) for q in queries) < _COL_SIDE_MIN):
        return [fn(*args, **(kwargs or {})) for fn, args, kwargs in queries]
    pool = _side_pool(min(nth, len(queries)) - 1)
    futs = [pool.submit(_one_thread, fn, args, kwargs or {}) for fn, args, kwargs in queries[1:]]
    fn, args, kwargs = queries[0]
    first = _one_thread(fn, args, kwargs or {})
    return [first] + [f.result() for f in futs]


def _query_size(q) -> int:
    """The box count of a :func:`column_queries` query (both sets of a pair query)."""
    fn, args, _ = q
    if fn is column_query_pairs or getattr(fn, "__name__", "") == "column_query_pairs":
        return int(np.shape(args[0])[0]) + int(np.shape(args[2])[0])
    return int(np.shape(args[0])[0])


# --------------------------------------------------------------------------------------------
# Canonical pair order
# --------------------------------------------------------------------------------------------


@njit(cache=True)
def _sort_pairs_kernel(pairs, n_a, rank_a, rank_b, tmp, cnt):
    """Sort the rows of ``pairs`` by (key of first, key of second) in place, the key of a
    primitive its ``rank`` (a permutation; empty: the index itself): a counting sort on the
    first key into ``tmp`` (stable), then an insertion sort on the second key within each run
    of equal first keys (short runs: a primitive's candidates), copied back. ``cnt``: n_a + 1
    ints."""
    m = pairs.shape[0]
    ra = rank_a.shape[0] > 0
    rb = rank_b.shape[0] > 0
    cnt[:] = 0
    for r in range(m):
        a = rank_a[pairs[r, 0]] if ra else pairs[r, 0]
        cnt[a + 1] += 1
    for a in range(n_a):
        cnt[a + 1] += cnt[a]
    for r in range(m):
        a = rank_a[pairs[r, 0]] if ra else pairs[r, 0]
        p = cnt[a]
        cnt[a] = p + 1
        tmp[p, 0] = pairs[r, 0]
        tmp[p, 1] = pairs[r, 1]
    # cnt[a] is now the end of run a (the start of run a + 1)
    s = 0
    for a in range(n_a):
        e = cnt[a]
        for p in range(s + 1, e):
            b = tmp[p, 1]
            kb = rank_b[b] if rb else b
            q = p - 1
            while q >= s and (rank_b[tmp[q, 1]] if rb else tmp[q, 1]) > kb:
                tmp[q + 1, 1] = tmp[q, 1]
                q -= 1
            tmp[q + 1, 1] = b
        s = e
    for r in range(m):
        pairs[r, 0] = tmp[r, 0]
        pairs[r, 1] = tmp[r, 1]


_NO_RANK = np.zeros(0, dtype=np.int64)


def sort_pairs(pairs, n_a: int, out: PairBuffer | None = None, rank_a=None,
               rank_b=None) -> np.ndarray:
    """Sort candidate rows ``(i, j)`` (``0 <= i < n_a``) in place by ``(rank_a[i], rank_b[j])``
    (a rank left out: the index itself) and return them: a canonical order, the same whichever
    query (trees or column grid) found the set. ``out``: the buffer the pairs came from, whose
    scratch is reused (else one is allocated)."""
    m = pairs.shape[0]
    if m < 2:
        return pairs
    tmp = out.scratch_rows(m) if out is not None else np.empty((m, 2), dtype=np.int64)
    cnt = (out._sort_counts(n_a + 1) if out is not None
           else np.empty(n_a + 1, dtype=np.int64))
    _sort_pairs_kernel(pairs, int(n_a), _NO_RANK if rank_a is None else rank_a,
                       _NO_RANK if rank_b is None else rank_b, tmp, cnt)
    return pairs


@njit(cache=True, inline="always")
def _spread32(v):
    """The low 32 bits of ``v`` spread to the even bits of a 64-bit integer."""
    v &= 0xFFFFFFFF
    v = (v | (v << 16)) & 0x0000FFFF0000FFFF
    v = (v | (v << 8)) & 0x00FF00FF00FF00FF
    v = (v | (v << 4)) & 0x0F0F0F0F0F0F0F0F
    v = (v | (v << 2)) & 0x3333333333333333
    v = (v | (v << 1)) & 0x5555555555555555
    return v


@njit(cache=True, inline="always")
def _compact32(v):
    """The inverse of :func:`_spread32`: the even bits of ``v`` packed into 32."""
    v &= 0x5555555555555555
    v = (v | (v >> 1)) & 0x3333333333333333
    v = (v | (v >> 2)) & 0x0F0F0F0F0F0F0F0F
    v = (v | (v >> 4)) & 0x00FF00FF00FF00FF
    v = (v | (v >> 8)) & 0x0000FFFF0000FFFF
    v = (v | (v >> 16)) & 0x00000000FFFFFFFF
    return v


@njit(cache=True)
def _zsort_kernel(pairs, rank_a, rank_b, self_mode, bits, key, key2, inv_a, inv_b, cnt):
    """Sort the rows of ``pairs`` in place by the Z-order (bit interleaving) of their ranks
    ``(rank_a[i], rank_b[j])`` (self mode: of the smaller and the larger rank; the rows are
    ``i < j``): an LSD radix sort of the keys alone, 11 bits a pass, over their ``bits`` low
    bits, then every row decoded from its key through the inverse ranks ``inv_a``, ``inv_b``
    (distinct rows have distinct keys, so the order is total). ``key``, ``key2``: int64
    scratch of the row count, ``cnt``: 2049 ints."""
    m = pairs.shape[0]
    for i in range(rank_a.shape[0]):
        inv_a[rank_a[i]] = i
    for i in range(rank_b.shape[0]):
        inv_b[rank_b[i]] = i
    for r in range(m):
        ka = rank_a[pairs[r, 0]]
        kb = rank_b[pairs[r, 1]]
        if self_mode and kb < ka:
            ka, kb = kb, ka
        key[r] = (_spread32(ka) << 1) | _spread32(kb)
    src, dst = key, key2
    shift = 0
    while shift < bits:
        cnt[:] = 0
        for r in range(m):
            cnt[((src[r] >> shift) & 2047) + 1] += 1
        for d in range(2048):
            cnt[d + 1] += cnt[d]
        for r in range(m):
            d = (src[r] >> shift) & 2047
            q = cnt[d]
            cnt[d] = q + 1
            dst[q] = src[r]
        src, dst = dst, src
        shift += 11
    for r in range(m):
        k = src[r]
        i = inv_a[_compact32(k >> 1)]
        j = inv_b[_compact32(k)]
        if self_mode and j < i:
            i, j = j, i
        pairs[r, 0] = i
        pairs[r, 1] = j


def zsort_pairs(pairs, rank_a, rank_b, self_mode: bool = False,
                out: PairBuffer | None = None) -> np.ndarray:
    """Sort candidate rows ``(i, j)`` in place by the Z-order of ``(rank_a[i], rank_b[j])``
    (self pairs: of their smaller and larger rank) and return them. With the Morton ranks of
    the primitives (:func:`morton_rank`: the trees' leaf order) this is about the order in which
    a simultaneous traversal of two trees meets the pairs (pairs of two nearby primitives
    together, block by block), but canonical: the same whichever query found the set. ``out``:
    the buffer the pairs came from (its scratch is reused)."""
    m = pairs.shape[0]
    if m < 2:
        return pairs
    top = max(int(rank_a.shape[0]), int(rank_b.shape[0]), 2) - 1
    bits = 2 * top.bit_length()
    if bits > 64:
        raise ValueError("zsort_pairs: ranks above 2^32")
    na, nb = int(rank_a.shape[0]), int(rank_b.shape[0])
    if out is not None:
        key, key2 = out._zsort_keys(m)
        inv = out._sort_counts(2049 + na + nb)
    else:
        key, key2 = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
        inv = np.empty(2049 + na + nb, dtype=np.int64)
    _zsort_kernel(pairs, rank_a, rank_b, bool(self_mode), bits, key, key2, inv[2049:2049 + na],
                  inv[2049 + na:], inv[:2049])
    return pairs


@njit(cache=True)
def _inverse_perm(order, rank):
    for k in range(order.shape[0]):
        rank[order[k]] = k


def morton_rank(lo, hi, rank=None) -> np.ndarray:
    """The position of every box in the Morton order of the box centres (the trees' leaf
    order, ties by index): a permutation of ``0 .. m-1``, for :func:`sort_pairs`."""
    n = lo.shape[0]
    rank = np.empty(n, dtype=np.int64) if rank is None else rank
    if n:
        codes = np.empty(n, dtype=np.int64)
        _morton_codes(lo, hi, codes)
        _inverse_perm(np.argsort(codes, kind="stable"), rank)
    return rank
