"""Bounding volume hierarchy over triangles, built once per scene on the host.

Binned surface-area-heuristic build, processed one tree level at a time so that the
per-primitive work is numpy operations over all primitives of that level; Python only
touches each node once (bookkeeping of children).
The result is a flat array of nodes in depth-first order: a node's left child is the next
node, its right child is stored; leaves reference a contiguous range of `prim_order`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

N_BINS = 16
MAX_LEAF = 4
TRAVERSAL_COST = 1.0      # relative to one triangle test


@dataclass
class Bvh:
    bmin: np.ndarray          # (N,3) float32
    bmax: np.ndarray          # (N,3) float32
    right_or_first: np.ndarray  # (N,) int32: right child (inner) or first primitive (leaf)
    count: np.ndarray         # (N,) int32: primitives in a leaf, 0 for inner nodes
    prim_order: np.ndarray    # (P,) int32: primitive index for each leaf slot
    depth: int

    @property
    def node_count(self) -> int:
        return len(self.count)


def build_bvh(tri_vertices: np.ndarray) -> Bvh:
    tri = np.asarray(tri_vertices, np.float64)
    n = len(tri)
    if n == 0:
        # An always-missing root keeps kernels uniform for sphere-only scenes.
        return Bvh(np.full((1, 3), 1.0, np.float32), np.full((1, 3), -1.0, np.float32),
                   np.zeros(1, np.int32), np.zeros(1, np.int32), np.zeros(0, np.int32), 1)
    pmin, pmax = tri.min(1), tri.max(1)
    cent = 0.5 * (pmin + pmax)

    # Tree under construction, in creation order: per node (start, end) into `order`.
    order = np.arange(n)
    starts, ends = [0], [n]
    children: list = [None]          # (left, right) node ids or None for leaves
    active = np.array([0])           # node ids still to split at this level
    depth = 1
    while active.size:
        s = np.array([starts[i] for i in active])
        e = np.array([ends[i] for i in active])
        split = _split_level(order, s, e, pmin, pmax, cent)   # per node: (axis or -1 for leaf, left count)
        next_active = []
        for k, node in enumerate(active):
            axis, pos = split[0][k], split[1][k]
            if axis < 0:
                continue
            mid = s[k] + pos
            l_id, r_id = len(starts), len(starts) + 1
            starts += [s[k], mid]
            ends += [mid, e[k]]
            children += [None, None]
            children[node] = (l_id, r_id)
            if mid - s[k] > MAX_LEAF:
                next_active.append(l_id)
            if e[k] - mid > MAX_LEAF:
                next_active.append(r_id)
        active = np.array(next_active, dtype=np.int64)
        depth += 1

    # Flatten to depth-first order (left child adjacent) with bounds per node.
    node_total = len(starts)
    dfs_index = np.empty(node_total, np.int64)
    out_order = []
    stack = [0]
    while stack:
        node = stack.pop()
        dfs_index[node] = len(out_order)
        out_order.append(node)
        if children[node] is not None:
            stack.append(children[node][1])
            stack.append(children[node][0])
    out_order = np.array(out_order)
    st, en = np.array(starts)[out_order], np.array(ends)[out_order]
    leaf = np.array([children[i] is None for i in out_order])
    right = np.array([dfs_index[children[i][1]] if children[i] is not None else 0 for i in out_order])
    bmin, bmax = _range_bounds(order, st, en, pmin, pmax)
    return Bvh(bmin.astype(np.float32), bmax.astype(np.float32),
               np.where(leaf, st, right).astype(np.int32),
               np.where(leaf, en - st, 0).astype(np.int32),
               order.astype(np.int32), depth)


def _range_bounds(order, st, en, pmin, pmax):
    """Bounds of primitives order[st:en] for many ranges at once (segment reductions)."""
    lo = pmin[order]
    hi = pmax[order]
    # Ranges nest, so reduceat over sorted unique boundaries would not work directly; a
    # sparse-table (doubling) range-min query answers every range in O(log n) numpy steps.
    return _range_query(lo, st, en, np.minimum), _range_query(hi, st, en, np.maximum)


def _range_query(values, st, en, op):
    n = len(values)
    table = [values]
    span = 1
    while span * 2 <= n:
        prev = table[-1]
        table.append(op(prev[:-span], prev[span:]))
        span *= 2
    length = en - st
    k = np.floor(np.log2(np.maximum(length, 1))).astype(np.int64)
    out = np.empty((len(st), 3))
    for level in np.unique(k):
        sel = k == level
        t = table[level]
        a = st[sel]
        b = en[sel] - (1 << level)
        out[sel] = op(t[a], t[b])
    return out


def _split_level(order, s, e, pmin, pmax, cent):
    """Choose a binned-SAH split for each node [s, e) and partition `order` in place.

    Returns (axis, count_left) per node; axis -1 makes the node a leaf."""
    m = len(s)
    counts = e - s
    node_of = np.repeat(np.arange(m), counts)
    offsets = np.cumsum(counts) - counts
    positions = np.repeat(s - offsets, counts) + np.arange(counts.sum())
    idx = order[positions]
    c = cent[idx]
    # Centroid bounds per node.
    cmin = np.full((m, 3), np.inf)
    cmax = np.full((m, 3), -np.inf)
    np.minimum.at(cmin, node_of, c)
    np.maximum.at(cmax, node_of, c)
    ext = cmax - cmin
    scale = np.where(ext > 0, N_BINS * (1 - 1e-9) / np.where(ext > 0, ext, 1), 0)
    bins = np.clip(((c - cmin[node_of]) * scale[node_of]).astype(np.int64), 0, N_BINS - 1)  # (P,3)

    lo, hi = pmin[idx], pmax[idx]
    best_cost = np.full(m, np.inf)
    best_axis = np.full(m, -1)
    best_bin = np.zeros(m, np.int64)
    for axis in range(3):
        key = node_of * N_BINS + bins[:, axis]
        bcount = np.bincount(key, minlength=m * N_BINS).reshape(m, N_BINS)
        bmin = np.full((m * N_BINS, 3), np.inf)
        bmax = np.full((m * N_BINS, 3), -np.inf)
        np.minimum.at(bmin, key, lo)
        np.maximum.at(bmax, key, hi)
        bmin = bmin.reshape(m, N_BINS, 3)
        bmax = bmax.reshape(m, N_BINS, 3)
        # Prefix (left) and suffix (right) sweeps over bins.
        lmin = np.minimum.accumulate(bmin, axis=1)
        lmax = np.maximum.accumulate(bmax, axis=1)
        rmin = np.minimum.accumulate(bmin[:, ::-1], axis=1)[:, ::-1]
        rmax = np.maximum.accumulate(bmax[:, ::-1], axis=1)[:, ::-1]
        lcount = np.cumsum(bcount, axis=1)
        # Split after bin b: left = bins[0..b], right = bins[b+1..]
        la = _half_area(lmin[:, :-1], lmax[:, :-1])
        ra = _half_area(rmin[:, 1:], rmax[:, 1:])
        nl = lcount[:, :-1]
        nr = counts[:, None] - nl
        cost = np.where((nl > 0) & (nr > 0), la * nl + ra * nr, np.inf)
        b = np.argmin(cost, axis=1)
        cb = cost[np.arange(m), b]
        better = (cb < best_cost) & (ext[:, axis] > 0)
        best_cost = np.where(better, cb, best_cost)
        best_axis = np.where(better, axis, best_axis)
        best_bin = np.where(better, b, best_bin)

    # Compare with not splitting: leaf cost = count * area(node).
    nmin = np.full((m, 3), np.inf)
    nmax = np.full((m, 3), -np.inf)
    np.minimum.at(nmin, node_of, lo)
    np.maximum.at(nmax, node_of, hi)
    node_area = np.maximum(_half_area(nmin, nmax), 1e-300)
    split_cost = TRAVERSAL_COST + best_cost / node_area
    leaf_ok = (counts <= MAX_LEAF) | ((split_cost >= counts) & (counts <= 16))
    fallback = ~np.isfinite(best_cost) & ~leaf_ok   # all centroids equal: split in the middle
    best_axis = np.where(leaf_ok, -1, best_axis)

    # Partition each node's range: stable sort by (node, side).
    side = np.zeros(len(idx), np.int64)
    ax = best_axis[node_of]
    has = ax >= 0
    side[has] = bins[has, ax[has]] > best_bin[node_of][has]
    # Nodes with identical centroids: split by position within the node.
    pos_in_node = np.arange(len(idx)) - np.repeat(offsets, counts)
    fb = fallback[node_of]
    side[fb] = pos_in_node[fb] >= (counts[node_of][fb] // 2)
    best_axis = np.where(fallback, 0, best_axis)
    perm = np.lexsort((side, node_of))
    order[positions] = idx[perm]
    n_left = np.bincount(node_of, weights=(side == 0), minlength=m).astype(np.int64)
    return best_axis, n_left


def _half_area(lo, hi):
    d = np.maximum(hi - lo, 0)
    d = np.where(np.isfinite(d), d, 0)
    return d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0]
