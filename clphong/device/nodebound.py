"""The light tree's node bounds on the device (kernels/node_bound.cl ``node_terms``).

The host's cut (clphong/device/culling.py ``_tree_cut``) bounds thousands of
(tile, node) pairs per tile; :func:`~clphong.model.light_tree.cluster_terms`, in
float64 numpy, costs about 1–2 µs a pair. The kernel computes the same terms in
double, one work-item a pair, for the tree's point-light nodes; the host takes
their largest channel as before (:func:`~clphong.model.light_tree.cluster_bounds`
``terms=``). Nodes with a spot's cone, and devices without double, keep the numpy
form.
"""

from __future__ import annotations

import copy

import numpy as np

from ..core.floats import U
from ..model.light_tree import LightTree, SpecularModel, TileBoxes, _sum3, leaf_ranges
from ..model.taylor import THETA_POINTS

#: Doubles per tile record (TILE_DOUBLES), per node record before its falloff's
#: turning points (NODE_DOUBLES) and after them (TAYLOR_DOUBLES: the Taylor term's),
#: kernels/node_bound.cl.
TILE_DOUBLES = 18
NODE_DOUBLES = 21
TAYLOR_DOUBLES = 38
#: Work-items per work-group.
LOCAL = 64


def node_records(tree: LightTree, origin) -> np.ndarray:
    """(K, NODE_DOUBLES + turning points + TAYLOR_DOUBLES) float64: each node's box
    (rebased), falloff, radiance and moments with its float32 record's roundings added,
    as :func:`~clphong.model.light_tree.cluster_terms` forms them, then what its Taylor
    term needs (:func:`~clphong.model.light_tree.taylor_term`)."""
    o = np.asarray(origin, np.float64)
    Rk = tree.radiance
    rp = U * (np.sqrt(_sum3((tree.position - o) ** 2)) + np.abs(o).max())[..., None]
    M = tree.moment + Rk * rp
    F = tree.first + Rk * rp
    Q = tree.quadratic + Rk * rp * (rp + 2 * tree.moment / np.maximum(Rk, 1e-300))
    one, two = tree.peaks
    K = tree.n_nodes
    return np.ascontiguousarray(np.concatenate(
        [tree.lo - o, tree.hi - o, tree.attenuation, Rk, M, F, Q, one, two,
         # the Taylor term's (TAYLOR_DOUBLES): |A‴|'s turning points, the float64
         # representative (rebased), its moments per channel, the record's rounding
         tree.third_peaks, tree.position - o, tree.first_vector.reshape(K, 9),
         tree.second_moment.reshape(K, 18), tree.third_moment, rp], axis=1), np.float64)


def tile_records(tiles: TileBoxes) -> np.ndarray:
    """(T, TILE_DOUBLES) float64: each tile's boxes of P and n, D and S."""
    return np.ascontiguousarray(np.concatenate(
        [tiles.lo, tiles.hi, tiles.nlo, tiles.nhi, tiles.D,
         np.broadcast_to(tiles.S, tiles.D.shape)], axis=1), np.float64)


class DeviceNodeTerms:
    """``node_terms`` for a tree (its node records on the device, once) and, after
    :meth:`for_tiles`, a set of tiles: called with pair rows ``t`` (tile indices) and
    ``k`` (node indices), it returns their (P, 3) terms."""

    def __init__(self, runtime, tree: LightTree, spec: SpecularModel, origin, tiles=None):
        import pyopencl as cl

        self.runtime = runtime
        one, two = tree.peaks
        lobe = spec.exponent is not None and spec.exponent >= 1
        self.K = float(spec.exponent) if lobe else 0.0
        self.eye = np.asarray(spec.eye, np.float64)
        self.prog = runtime.program("node_bound.cl", {
            "N_ONE": one.shape[1], "N_TWO": two.shape[1], "LOBE": int(lobe),
            "BLINN": int(spec.blinn), "FRESNEL": int(spec.fresnel),
            "PERSPECTIVE": int(spec.perspective), "THETA_POINTS": THETA_POINTS})
        ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
        nodes = node_records(tree, origin)
        self.node_doubles = nodes.shape[1]
        self.nodes = cl.Buffer(runtime.context, ro, hostbuf=nodes)
        self.tiles = None if tiles is None else self._tiles_buffer(tiles)

    def _tiles_buffer(self, tiles: TileBoxes):
        import pyopencl as cl

        return cl.Buffer(self.runtime.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=tile_records(tiles))

    def for_tiles(self, tiles: TileBoxes) -> "DeviceNodeTerms":
        """The same tree's terms over ``tiles`` (the node records are shared)."""
        other = copy.copy(self)
        other.tiles = self._tiles_buffer(tiles)
        return other

    @staticmethod
    def usable(runtime, tree: LightTree) -> bool:
        """Whether the device can bound this tree's nodes: double, and no spot's cone."""
        return bool(runtime.has_fp64) and not (tree.cone[:, 3] > 0).any()

    def __call__(self, t, k) -> np.ndarray:
        import pyopencl as cl

        t = np.ascontiguousarray(t, np.uint32).reshape(-1)
        k = np.ascontiguousarray(k, np.uint32).reshape(-1)
        n = len(t)
        out = np.empty((n, 3), np.float64)
        if n == 0:
            return out
        ctx, queue = self.runtime.context, self.runtime.queue
        ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
        tb, kb = cl.Buffer(ctx, ro, hostbuf=t), cl.Buffer(ctx, ro, hostbuf=k)
        ob = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
        kern = self.runtime.kernel(self.prog, "node_terms")
        with self.runtime.lock:
            kern.set_args(self.tiles, self.nodes, np.uint32(self.node_doubles), tb, kb,
                          np.uint32(n), *(np.float64(x) for x in self.eye), np.float64(self.K), ob)
            ev = cl.enqueue_nd_range_kernel(queue, kern, (-(-n // LOCAL) * LOCAL,), (LOCAL,))
        cl.enqueue_copy(queue, out, ob, wait_for=[ev]).wait()
        return out

    def tile_cut(self, tree: LightTree, scale, tile_super, kept, extra_ranges, extra,
                 light_rec, node_rec, *, cap: int, limit: float = 1.0 - 1e-9, reserve: int = 0):
        """kernels/node_bound.cl ``tile_cut`` over this object's tiles (one cut each):
        ``scale`` (T, 3) each channel's 1/budget; ``tile_super`` (T,) each tile's
        super-tile, whose culling kept the lights of ``kept`` (S, words) bits and
        whose lights under no node are ``extra[o:o + c]`` for its ``extra_ranges``
        (S, 2) (o, c), as records; ``light_rec`` / ``node_rec``: the records of the
        leaves and the internal nodes. Returns (counts (T, 3) uint32: each list's
        length at lists + t·cap (CUT_OVERFLOW where cap entries could not hold it), its
        clusters and the lights they stand for; sums (T,): the cut's largest channel's sum
        of bounds, in units of that channel's budget; the lists buffer: T·cap entries, then ``reserve`` more)."""
        import pyopencl as cl

        ctx, queue = self.runtime.context, self.runtime.queue
        scale = np.ascontiguousarray(scale, np.float64).reshape(-1, 3)
        n = len(scale)
        ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR

        def buf(a, dtype):
            a = np.ascontiguousarray(a, dtype).reshape(-1)
            return cl.Buffer(ctx, ro, hostbuf=a if a.size else np.zeros(1, dtype))

        kids = buf(tree.children, np.int32)
        roots = np.asarray(tree.levels[0] if tree.levels else [], np.uint32)
        args = [self.tiles, buf(scale, np.float64), self.nodes, np.uint32(self.node_doubles),
                kids, np.uint32(tree.n_leaves), buf(roots, np.uint32), np.uint32(roots.size),
                buf(kept, np.uint32), np.uint32(np.asarray(kept).shape[-1]),
                buf(tile_super, np.uint32), buf(extra_ranges, np.uint32), buf(extra, np.uint32),
                buf(light_rec, np.uint32), buf(node_rec, np.uint32),
                buf(_node_sizes(tree), np.uint32), *(np.float64(x) for x in self.eye), np.float64(self.K), np.float64(limit),
                np.uint32(cap)]
        chunk = min(CUT_CHUNK, max(64, CUT_HEAP_BYTES // (44 * cap)), max(n, 1))
        heap_b = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, chunk * cap * 8 * 4)
        heap_k = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, chunk * cap * 4 * 3)
        lists = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, max(n * cap + reserve, 1) * 4)
        counts_b = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, max(n, 1) * 12)
        sums_b = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, max(n, 1) * 8)
        kern = self.runtime.kernel(self.prog, "tile_cut")
        ev = None
        with self.runtime.lock:
            for t0 in range(0, n, chunk):
                m = min(chunk, n - t0)
                kern.set_args(*args, heap_b, heap_k, lists, counts_b, sums_b, np.uint32(t0),
                              np.uint32(m))
                ev = cl.enqueue_nd_range_kernel(queue, kern, (-(-m // CUT_LOCAL) * CUT_LOCAL,),
                                                (CUT_LOCAL,))
        counts = np.zeros((n, 3), np.uint32)
        sums = np.zeros(n, np.float64)
        if n:
            cl.enqueue_copy(queue, counts, counts_b, wait_for=[ev])
            cl.enqueue_copy(queue, sums, sums_b).wait()
        return counts, sums, lists


def _node_sizes(tree: LightTree) -> np.ndarray:
    """(K,) the lights under each internal node."""
    start, end, _ = leaf_ranges(tree)
    return (end - start).astype(np.uint32)


#: kernels/node_bound.cl tile_cut's mark of a list that cap entries could not hold.
CUT_OVERFLOW = 0xFFFFFFFF
#: Tiles per launch of ``tile_cut`` (its heaps and slots: 44 bytes for each of cap
#: entries, reused across launches), fewer where they would pass CUT_HEAP_BYTES (64 at
#: least).
CUT_CHUNK = 1024
CUT_HEAP_BYTES = 64 << 20
#: Work-items per work-group of ``tile_cut``.
CUT_LOCAL = 16
