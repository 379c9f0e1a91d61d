"""Host side of error-bounded tiled light culling (``kernels/cull.cl``).

Plain attenuation ``1/(c0 + c1·d + c2·d²)`` never reaches zero, so a point
light has no radius to cull by. Instead each 16×16 screen tile gets, from its
world-space box of P, the box of its normals and the largest ``C_d·k_d`` and
``k_s·C_s`` it holds, an upper bound of every light's contribution to any of its
pixels; lights are dropped only while the sum of the dropped bounds stays within
the budget ``ε`` (output radiance, per pixel and channel). So the culling error
of every pixel is at most ``ε``; ``ε = 0`` drops only lights whose bound is
exactly 0 (black lights or black tiles), which leaves the sum bit-identical.

The lists are built on the device in two passes over the lights
(``cull_count``: capacities; ``cull_write``: the indices, in light order), at
two levels: super-tiles (8×8 tiles, or LANES×LANES tiles where a work-item's
LANES tiles must share one: 256×256 pixels with 16 lanes) against all lights
with ε/4, then each 16×16 tile against its super-tile's list with the other
3ε/4. The
host only packs the light records, takes a prefix sum of the per-tile
capacities and allocates the list buffer. Directional and ambient lights are
never culled.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..core.floats import U
from ..model.light_tree import (
    LightTree,
    SpecularModel,
    TileBoxes,
    choose_cut,
    cluster_bounds,
    group_of,
    leaf_ranges,
    representative_records,
    threshold_cut,
)
from .nodebound import CUT_OVERFLOW, DeviceNodeTerms
from .runtime import float4

#: float4s per point-light record (POINT_LIGHT_FLOAT4S in kernels/include/clphong.h):
#: (x, y, z, c0) (r, g, b, c1) (c2, ax, ay, az) (s, o, 0, 0), with a spot's unit
#: axis a and cone factor t², t = clamp(cos θ·s + o, 0, 1) (a point light: a = 0,
#: s = 0, o = 1, a factor of exactly 1).
POINT_RECORD = 4
#: float4s per cull-light record (CULL_LIGHT_FLOAT4S in kernels/cull.cl).
CULL_RECORD = 5

#: Screen tile edge in pixels (``CULL_TILE`` in kernels/cull.cl).
TILE = 16
#: Super-tile edge in tiles (``CULL_SUPER``) with up to 8 lanes; see :func:`super_tiles`.
SUPER = 8
#: Share of the budget the super-tile level may use; the tiles get the rest. The
#: coarse level pre-filters (its lists are what every tile's passes read), and a
#: tile keeps fewer lights the more budget it has. Bench, small-reach scene,
#: 65 536 lights, ε = 10⁻³, culling + shading: 1/8 1.80 s, 1/4 1.73 s, 0.4 1.75 s.
COARSE_SHARE = 0.25
#: Largest light list the culling pass may allocate, in entries (4 bytes each).
#: Beyond it culling would save little; the frame is shaded brute force.
MAX_LIST_ENTRIES = 1 << 27
#: Work-items per work-group of the culling kernels.
CULL_LOCAL = 8
#: Above this mean kept fraction the frame is shaded brute force with the lists
#: unused: walking a tile's list costs about 1.08x brute force per pair (its
#: indices are loaded, not counted), and the culling kernels about 4 % of a
#: brute-force 1080p frame at 256 lights, so lists that keep more than ~88 % lose.
#: At 0.85 culling costs at most ~1.05x brute force where it cannot drop
#: (256 lights, c2 = 20, 98.9 % kept: 1.13x before this fallback), and keeps its
#: gain where it can.
BRUTE_ABOVE = 0.85
#: The light tree (clphong/model/light_tree.py) is tried where the tiles' lists
#: from culling alone keep more than this share of the point lights on average:
#: below it culling does well (the small-reach scene keeps 0.2 %: its super-tiles
#: keep more than a quarter, and clusters there made the tiles keep 3.2 %), and
#: the host's cut is not worth its time.
TREE_ABOVE = 0.25
#: Share of the budget the tree's clusters may use where a cut takes clusters; the
#: tiles' culling gets what the super-tiles and the tree leave (1 − 1/4 − 1/2).
#: Where the tree is tried, culling drops little (the super-tiles kept more than
#: TREE_ABOVE): the clustered bench scene, 4096 lights at ε = 10⁻², keeps 45 % of
#: the lights with 1/4, 33 % with 1/2.
TREE_SHARE = 0.5
#: Where a tree is given, the tiles' pass without it runs first on a sample of the
#: super-tiles: one in PROBE_EVERY, rounded up (evenly spread over those with shaded
#: tiles; all where there is one). Where the sample keeps more than TREE_ABOVE the
#: tree goes first, and the whole pass runs only if the tree's lists keep more than
#: 1/PROBE_MARGIN of what the sample foretells for the whole pass; then the shorter
#: lists win, as without a sample. That pass, over ~65 536 candidates a tile, was a
#: quarter of the `clusters` frame at 65 536 lights (relative 10⁻², Ice Lake: the tree
#: kept 1/15 of it) and was thrown away; the sample costs an eighth of it.
PROBE_EVERY = 8
#: How much shorter than the sample's forecast the tree's lists must be to be taken
#: without the whole pass. One middle super-tile of six foretold 1.31x the whole pass
#: (tests/device/test_bands.py's frame, 400 lights: 47.8 % kept against 36.5 %), and
#: there the pass without the tree wins; the choice changes only speed, never the bound.
PROBE_MARGIN = 2.0
#: The host's cut takes its node bounds' terms from kernels/node_bound.cl where the
#: device computes in double and the tree has no spot's cone (False: numpy always).
NODE_TERMS_ON_DEVICE = True
#: Super-tiles per chunk of the host's cut (its tables are (chunk, nodes) bool; the
#: bounds are formed PAIR_CHUNK pairs at a time, clphong.model.light_tree).
TREE_CHUNK = 64
#: Trees of at least this many internal nodes are cut from the top down
#: (:func:`~clphong.model.light_tree.threshold_cut`), smaller ones from their whole
#: table of bounds; the same cut either way (but where a sum lies within rounding of
#: the budget: threshold_cut's docstring). Measured on the bench at 1080p (Ice Lake,
#: 2 cores; 40 super-tiles), top down against the whole table: 65 535 nodes, relative
#: 10⁻¹ 0.17 / 3.16 s, relative 10⁻² 0.94 / 3.16 s; 16 383 nodes, relative 10⁻² 0.44 /
#: 0.62 s, absolute 10⁻³ 0.63 / 0.53 s; 4 095 nodes 0.18–0.19 / 0.11 s. Where the cut
#: is deep the top-down search bounds nearly every pair anyway, in pairs, which costs
#: more a pair than the table's broadcasts.
TOP_DOWN_NODES = 16384
#: Super-tiles a whole table of bounds is formed for at once (its (chunk, nodes, 3)
#: float64 temporaries).
DENSE_CHUNK = 8


def super_tiles(lanes: int) -> int:
    """Super-tile edge in tiles for ``lanes`` pixels per work-item: ``SUPER``, or
    ``lanes`` when wider, because a work-item's ``lanes`` tiles must share one."""
    return max(SUPER, int(lanes))


def pack_cull_lights(point: np.ndarray, n_point: int, representative=None,
                     radius=None) -> np.ndarray:
    """Cull records, 5 float4 per light (CULL_RECORD), from the float path's point records.

    The positions, coefficients and radiance are the float32 values the float
    path reads; the fp64 path reads their float64 originals, which differ by
    a rounding each, inside the bound's margins (the 32u of b and p_scale's
    8u·κ_p; tests/test_cull.py checks the bound against float64). Added, in
    float64 then rounded conservatively:

    * ``vertex``: ``−c1/(2c2)`` where ``c1 < 0 < c2`` (rounded up), else 0; left
      of it p decreases, so p's minimum over ``d ≥ d⁻`` is at the vertex;
    * ``p_vertex_lo``: a lower bound of ``p(vertex) = c0 − c1²/(4c2)``;
    * ``p_scale = 1 − 8u·κ_p`` (rounded down), ``κ_p = max_d (c0 + |c1|d + c2d²)/p(d)``
      the condition number of p: the float32 p is ≥ p_scale·p; 0 (no bound, the
      light is never culled) where ``c0 < 0``, or κ_p is too large; ``c0 = 0``
      with ``c1, c2 ≥ 0`` (1/d²) is bounded like any increasing p;
    * ``|L|``: the distance of the (rebased) light from the frame origin, for
      the error of n·l;
    * a spot's axis and cone ``(s, o)`` as the point record holds them (a point
      light's ``s = 0``: no cone), for the cone's bound of the factor t²;
    * 1 where a falloff coefficient is nonzero and below FLT_MIN, or where the record
      is one of the light tree's representatives (``representative``: (n,) bool) and
      no ``radius`` is given: the relative budget's floor (``tile_floor``) leaves such
      a light out;
    * a representative's ``radius`` ((n,) float64, read at the representatives): the
      radius of a ball about its float32 record's position that holds every light it
      stands for (rounded up), with which ``tile_floor`` bounds their sum below.
    """
    rec = np.zeros((max(n_point, 1), CULL_RECORD, 4), np.float32)
    if n_point == 0:
        return rec.reshape(-1, 4)
    pt = point.reshape(-1, POINT_RECORD, 4)[:n_point]
    pos = pt[:, 0, :3].astype(np.float64)
    c0 = pt[:, 0, 3].astype(np.float64)
    c1 = pt[:, 1, 3].astype(np.float64)
    c2 = pt[:, 2, 0].astype(np.float64)
    rad = np.abs(pt[:, 1, :3])      # |L|: the bound is of |contribution|
    dipping = (c1 < 0) & (c2 > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.where(dipping, -c1 / (2 * c2), 0.0)
        p_vertex = np.where(dipping, c0 - c1 * c1 / (4 * c2), c0)
        root = 2 * np.sqrt(np.maximum(c0 * c2, 0.0))
        kappa = np.where(dipping, (root - c1) / (root + c1), 1.0)
    # c0 = 0 with c1, c2 ≥ 0 (physical falloff, 1/d²): p increases from p(0) = 0,
    # so p⁻ = p(d⁻) > 0 off the tile's box, and 0 (no bound: kept) inside it.
    physical = (c0 == 0) & (c1 >= 0) & (c2 >= 0) & ((c1 > 0) | (c2 > 0))
    ok = (((c0 > 0) & (p_vertex > 0)) | physical) & np.isfinite(kappa) & (kappa > 0) & (kappa < 1e5)
    p_scale = np.where(ok, 1.0 - 8.0 * U * np.where(ok, kappa, 1.0), 0.0)
    rec[:, 0, :3] = pos
    rec[:, 0, 3] = pt[:, 0, 3]
    rec[:, 1, 0] = c1
    rec[:, 1, 1] = c2
    # conservative roundings: vertex up, the lower bounds down
    rec[:, 1, 2] = np.nextafter(vertex.astype(np.float32), np.float32(np.inf))
    pv = (p_vertex * (1 - 4 * U)).astype(np.float32)
    rec[:, 1, 3] = np.where(ok, np.nextafter(pv, np.float32(0)), 0)
    rec[:, 2, 0] = np.nextafter(p_scale.astype(np.float32), np.float32(0)).clip(0, 1)
    rec[:, 2, 1:4] = rad
    rec[:, 3, 0] = np.nextafter(np.sqrt((pos * pos).sum(axis=1)).astype(np.float32),
                                np.float32(np.inf))
    rec[:, 3, 1:4] = pt[:, 2, 1:4]        # a spot's axis, as the shading kernel reads it
    rec[:, 4, 0:2] = pt[:, 3, 0:2]        # (s, o), as the shading kernel reads them
    # no floor (relative budget) from a light with a falloff coefficient below FLT_MIN: the
    # kernels read it as 0 (denormals flushed), an absolute, not relative, rounding
    coef = np.abs(np.stack([c0, c1, c2], axis=1))
    rec[:, 4, 2] = ((coef > 0) & (coef < np.finfo(np.float32).tiny)).any(axis=1)
    if representative is not None:
        rep = np.asarray(representative, bool)[:n_point]
        if radius is None:
            rec[rep, 4, 2] = 1
        else:
            r = np.asarray(radius, np.float64)[:n_point][rep]
            rec[rep, 4, 3] = np.nextafter(r.astype(np.float32), np.float32(np.inf))
    return rec.reshape(-1, 4)


def cluster_radius(tree: LightTree, layout: "ExtendedLayout", records: np.ndarray,
                   origin) -> np.ndarray:
    """(n + K,) float64: for each representative's record, the radius of a ball about its
    float32 (rebased) position that holds its node's box of lights (float64, rebased
    as the tile boxes are), rounded up; 0 for the lights' records."""
    pos = records.reshape(-1, POINT_RECORD, 4)[layout.node, 0, :3].astype(np.float64)
    o = np.asarray(origin, np.float64)
    far = np.maximum(np.abs(tree.hi - o - pos), np.abs(pos - (tree.lo - o)))
    # + the float64 roundings of the rebased corners, absolute (2⁻⁵¹ of their size each)
    reach = np.maximum(np.abs(tree.hi - o), np.abs(tree.lo - o)).max(axis=1)
    radius = np.zeros(len(layout.source))
    radius[layout.node] = (np.sqrt((far * far).sum(axis=1)) * (1 + 1e-9)
                           + 2.0 ** -51 * np.sqrt(3.0) * reach)
    return radius


@dataclass
class ListedTiles:
    """Per-tile light lists on the device, as the shading kernel reads them: (offset,
    count) per tile and the light indices, and the tiles' geometry (16×16 pixels,
    ``tiles_x`` a row; a work-item's tile is that of its first pixel)."""

    ranges: object            # cl.Buffer of uint2 (offset, count) per tile
    lights: object            # cl.Buffer of uint light indices
    width: int
    tiles_x: int
    n_tiles: int

    def kernel_args(self) -> list:
        return [self.ranges, self.lights, np.uint32(self.width), np.uint32(self.tiles_x),
                np.uint32(self.n_tiles)]


@dataclass
class TileLists(ListedTiles):
    """Per-tile point-light lists on the device, and what culling achieved."""

    kept: int                 # Σ over tiles of the kept lights
    n_point: int
    seconds: float            # device time of the three culling kernels
    active_tiles: int = 0     # tiles with at least one shaded pixel
    brute: bool = False       # the lists kept too much to pay off: shaded brute force
    #: with the light tree's clusters: the point records the lists index (each light
    #: group's lights, then its representatives: ExtendedLayout), float32 rebased and
    #: float64; each record's source (light j, or n_point + node k); with light groups,
    #: each group's end among them (the shading kernel's group table); else None
    records: np.ndarray | None = None
    records64: np.ndarray | None = None
    record_source: np.ndarray | None = None
    point_end: np.ndarray | None = None
    clusters: int = 0         # Σ over super-tiles of the clusters their cuts use
    covered: int = 0          # Σ over super-tiles of the lights those clusters stand for
    tree_seconds: float = 0.0  # the host's cut (bounds and choice)
    tree_nodes: int = 0       # the tree's internal nodes (possible clusters)
    tree_lights: int = 0      # lights under them
    tree_build_seconds: float = 0.0
    #: the cut was made per block of BLOCK_TILES² tiles (its lists the tiles' own)
    tree_blocks: bool = False
    #: with the relative budget: each tile's proven lower bound of its pixels' totals
    #: (the least channel; float64 array over the tiles, 0 where none; with light
    #: groups (G, tiles), each group's own), else None
    floors: np.ndarray | None = None
    #: the same for the super-tiles (SUPER×SUPER tiles, or lanes×lanes), numbered row by row
    coarse_floors: np.ndarray | None = None

    @property
    def pays(self) -> bool:
        """Whether shading through the lists beats brute force (:data:`BRUTE_ABOVE`)."""
        return self.kept_fraction <= BRUTE_ABOVE

    @property
    def kept_fraction(self) -> float:
        """Mean fraction of the point lights a tile with shaded pixels keeps."""
        return self.kept / max(self.active_tiles * self.n_point, 1)


#: Floats per tile record (T_PLANES in kernels/cull.cl).
T_PLANES = 26


def _n_pad(n_tiles: int, lanes: int) -> int:
    block = lanes * CULL_LOCAL
    return -(-n_tiles // block) * block


def _tile_bounds(runtime, prog, frame, g, mp, *, k_d, S, tile_size, tiles_x, tiles_y, lanes):
    """kernels/cull.cl tile_bounds: (tiles buffer, its event)."""
    import pyopencl as cl

    h, w = frame.shape
    n_tiles = tiles_x * tiles_y
    n_pad = _n_pad(n_tiles, lanes)
    tiles = cl.Buffer(runtime.context, cl.mem_flags.READ_WRITE, T_PLANES * n_pad * 4)
    k0 = runtime.kernel(prog, "tile_bounds")
    k0.set_args(g, mp, np.uint32(frame.stride), np.uint32(w), np.uint32(h * w),
                np.uint32(tile_size), np.uint32(tiles_x), np.uint32(n_tiles), np.uint32(n_pad),
                float4(*frame.origin), np.float32(k_d), float4(*S), tiles)
    return tiles, cl.enqueue_nd_range_kernel(runtime.queue, k0, (n_pad,), (CULL_LOCAL,))


def _merge_bounds(runtime, prog, fine, *, fine_tiles_x, fine_tiles_y, sup, tiles_x, tiles_y,
                  lanes, wait_for):
    """kernels/cull.cl merge_bounds: super-tile records from the tiles' (bit-identical
    to tile_bounds on the super-tiles, without reading the frame again)."""
    import pyopencl as cl

    n_tiles = tiles_x * tiles_y
    n_pad = _n_pad(n_tiles, lanes)
    tiles = cl.Buffer(runtime.context, cl.mem_flags.READ_WRITE, T_PLANES * n_pad * 4)
    k = runtime.kernel(prog, "merge_bounds")
    k.set_args(fine, np.uint32(fine_tiles_x), np.uint32(fine_tiles_y),
               np.uint32(_n_pad(fine_tiles_x * fine_tiles_y, lanes)), np.uint32(sup),
               np.uint32(tiles_x), np.uint32(n_tiles), np.uint32(n_pad), tiles)
    return tiles, cl.enqueue_nd_range_kernel(runtime.queue, k, (n_pad,), (CULL_LOCAL,),
                                             wait_for=wait_for)


def _cull_level(runtime, prog, tiles, bounds_events, lb, n_point, *, budget, tiles_x, tiles_y,
                lanes, candidates=None, super_tiles=0, floor=None):
    """One level, from its tile records: capacities, lists. Returns (ranges (n, 2) uint32
    host array, lists buffer, total kept, device seconds, the tiles' floors or None
    ((3, n), or (G, 3, n) with light groups: per channel), the budget each tile left
    unused (n,) float64: a lower bound, in units of the tile's budget (relative: of
    ``budget`` times its floor, in every channel), with the kernel's roundings taken
    off), or None when too long.

    ``floor``: the relative budget, ``budget`` a fraction of each pixel's own value:
    (directional records buffer, their number, ambient float4, the groups: their
    number and the point and directional ends, their ambient) for
    kernels/cull.cl ``tile_floor``, which gives each tile and channel ``budget·T⁻_c``
    (T⁻_c a proven lower bound of its pixels' totals in that channel, scaled by
    :data:`FLOOR_SCALE`); a light's bound is then taken per channel in units of that
    channel's budget."""
    import pyopencl as cl

    ctx, queue = runtime.context, runtime.queue
    mf = cl.mem_flags
    n_tiles = tiles_x * tiles_y
    n_pad = _n_pad(n_tiles, lanes)
    tau = cl.Buffer(ctx, mf.READ_WRITE, n_pad * 4)
    left = cl.Buffer(ctx, mf.READ_WRITE, n_pad * 4)
    cap = np.zeros(n_pad, np.uint32)
    capb = cl.Buffer(ctx, mf.READ_WRITE, cap.nbytes)
    if candidates is None:
        dummy = cl.Buffer(ctx, mf.READ_ONLY, 16)
        cand = (dummy, dummy, np.uint32(0))
    else:
        cand = (candidates[0], candidates[1], np.uint32(1))
    cand_args = (*cand, np.uint32(tiles_x), np.uint32(super_tiles))
    events = list(bounds_events)
    n_groups = floor[3] if floor is not None else 0
    planes = max(n_groups, 1)
    # per light group, one plane per channel
    tile_budget = cl.Buffer(ctx, mf.READ_WRITE, planes * 3 * n_pad * 4 if floor is not None else 16)
    if floor is not None:
        events.append(_floor_pass(runtime, prog, tiles, n_pad, lb, n_point, cand_args, floor,
                                  budget * FLOOR_SCALE, tile_budget, lanes, events[-1:]))
        group_args = (np.uint32(n_groups), floor[4])
    else:
        group_args = (np.uint32(0), cl.Buffer(ctx, mf.READ_ONLY, 16))
    budget_args = (tile_budget, np.uint32(floor is not None), *group_args)
    k1 = runtime.kernel(prog, "cull_count")
    k1.set_args(tiles, np.uint32(n_pad), lb, np.uint32(n_point), *cand_args,
                np.float32(budget), *budget_args, tau, left, capb)
    events.append(cl.enqueue_nd_range_kernel(queue, k1, (n_pad // lanes,), (CULL_LOCAL,),
                                             wait_for=events[-1:]))
    cl.enqueue_copy(queue, cap, capb, wait_for=events[-1:]).wait()
    total = int(cap[:n_tiles].sum(dtype=np.int64))
    if total > MAX_LIST_ENTRIES:
        return None
    offsets = np.zeros(n_pad, np.uint32)
    offsets[1:] = np.cumsum(cap[:-1], dtype=np.uint64).astype(np.uint32)
    ob = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=offsets)
    counts = np.zeros(n_pad, np.uint32)
    cb = cl.Buffer(ctx, mf.READ_WRITE, counts.nbytes)
    lists = cl.Buffer(ctx, mf.READ_WRITE, max(total, 1) * 4)
    k2 = runtime.kernel(prog, "cull_write")
    k2.set_args(tiles, np.uint32(n_pad), lb, np.uint32(n_point), *cand_args, *budget_args, tau,
                left, ob, cb, lists)
    events.append(cl.enqueue_nd_range_kernel(queue, k2, (n_pad // lanes,), (CULL_LOCAL,)))
    cl.enqueue_copy(queue, counts, cb, wait_for=events[-1:]).wait()
    ranges = np.stack([offsets[:n_tiles], counts[:n_tiles]], axis=1).astype(np.uint32)
    unused = np.zeros(n_pad, np.float32)
    cl.enqueue_copy(queue, unused, left).wait()
    # left: cull_count's ε′ − Σ (the dropped bounds' sum, rounded; ε′ the budget less the
    # reserve for the sum's and the scaling's roundings), less what cull_write then
    # dropped greedily: the reserve covers those subtractions' roundings too, so it is
    # at most the exact unused part but for its last roundings. Here in units of the
    # tile's budget (absolute: of ``budget``), less 64u relative and 64u of the budget.
    unused = unused[:n_tiles].astype(np.float64)
    if floor is None:
        unused = unused / budget if budget > 0 else np.zeros_like(unused)
    unused = np.maximum(unused * (1 - 64 * U) - 64 * U, 0.0)
    seconds = sum((e.profile.end - e.profile.start) * 1e-9 for e in events)
    floors = None
    if floor is not None:          # the tiles' floors T⁻_c (what tile_floor gave, over ε)
        floors = np.zeros((planes, 3, n_pad), np.float32)
        cl.enqueue_copy(queue, floors, tile_budget).wait()
        # over ε alone: the floor the budget rests on (FLOOR_SCALE included); per group
        # and channel
        floors = floors[..., :n_tiles].astype(np.float64) / budget if budget > 0 else None
        if floors is not None and not n_groups:
            floors = floors[0]
    return ranges, lists, int(counts[:n_tiles].sum(dtype=np.int64)), seconds, floors, unused


def _floor_pass(runtime, prog, tiles, n_pad, lb, n_point, cand_args, floor, scale, out, lanes,
                wait_for):
    """Launch kernels/cull.cl ``tile_floor``: each tile's (and light group's) ``scale``·T⁻_c
    into ``out`` (planes × 3 × n_pad float32), T⁻_c a proven lower bound of its pixels'
    totals in channel c (``floor``: :meth:`RelativeInput.floor_args`); its event."""
    import pyopencl as cl

    dirs, n_dir, ambient, n_groups, pend, dend, gamb = floor
    k0 = runtime.kernel(prog, "tile_floor")
    k0.set_args(tiles, np.uint32(n_pad), lb, np.uint32(n_point), *cand_args, dirs,
                np.uint32(n_dir), ambient, np.float32(scale), np.uint32(n_groups), pend, dend,
                gamb, out)
    return cl.enqueue_nd_range_kernel(runtime.queue, k0, (n_pad // lanes,), (CULL_LOCAL,),
                                      wait_for=wait_for)


def _tile_floors(runtime, prog, tiles, lb, n_point, floor, *, c_ranges, c_lists, tiles_x,
                 tiles_y, super_tiles, lanes, wait_for=()):
    """Each tile's T⁻_c (:func:`_floor_pass`, FLOOR_SCALE in) from its super-tile's list
    (``c_ranges``, ``c_lists``): (3, n_tiles) float64, or (G, 3, n_tiles) with light
    groups, and the pass's device seconds. A lower bound of every pixel's total: the lights the super-tile's culling
    dropped add nothing below 0 (the relative budget needs lights that do not subtract)."""
    import pyopencl as cl

    ctx = runtime.context
    n_tiles = tiles_x * tiles_y
    n_pad = _n_pad(n_tiles, lanes)
    planes = max(floor[3], 1)
    out = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, planes * 3 * n_pad * 4)
    crb = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                    hostbuf=np.ascontiguousarray(c_ranges))
    cand_args = (crb, c_lists, np.uint32(1), np.uint32(tiles_x), np.uint32(super_tiles))
    ev = _floor_pass(runtime, prog, tiles, n_pad, lb, n_point, cand_args, floor, FLOOR_SCALE,
                     out, lanes, list(wait_for))
    got = np.zeros((planes, 3, n_pad), np.float32)
    cl.enqueue_copy(runtime.queue, got, out, wait_for=[ev]).wait()
    got = got[..., :n_tiles].astype(np.float64)
    return (got if floor[3] else got[0]), (ev.profile.end - ev.profile.start) * 1e-9


#: The plan defines kernels/cull.cl reads; passing only these keeps one cull
#: program per material layout, whatever the shading variant (path, tone mapping).
CULL_DEFINES = ("HAS_SPECULAR", "MAP_KD", "MAP_KS", "MAP_H", "MAP_CS", "HAS_SPOT")


def build_tile_lists(runtime, plan, frame, point_records, n_point, *, budget, k_d, S,
                     gbuf_buffer=None, maps_buffer=None, tree=None, relative=None):
    """See :func:`_build_tile_lists`; holds the runtime's launch lock (its cached kernels)."""
    with runtime.lock:
        return _build_tile_lists(runtime, plan, frame, point_records, n_point, budget=budget,
                                 k_d=k_d, S=S, gbuf_buffer=gbuf_buffer, maps_buffer=maps_buffer,
                                 tree=tree, relative=relative)


@dataclass(frozen=True)
class RelativeInput:
    """What the relative budget's floor needs besides the point lights: the directional
    records as the shading kernel reads them (``pack_lights``), their number, and the
    ambient radiance ``k_a·Σ A`` per channel; with light groups, each group's ends of
    the point and directional runs and its ambient ``k_a·A_g`` (each group gets floors
    of its own). ``nonnegative``: every radiance is ≥ 0, so every term of a pixel's
    total is; where not, no tile has a floor (nothing is dropped but lights whose bound
    is 0)."""

    directional: np.ndarray
    n_dir: int
    ambient: np.ndarray
    nonnegative: bool
    point_end: np.ndarray = None          # (G,) uint32, or None without groups
    dir_end: np.ndarray = None
    group_ambient: np.ndarray = None      # (G, 3) float64

    @property
    def n_groups(self) -> int:
        return 0 if self.point_end is None else len(self.point_end)

    @classmethod
    def of(cls, scene, lights) -> "RelativeInput":
        arrays = scene.light_arrays
        n_dir = len(arrays["directional_direction"])
        d = lights.directional.reshape(-1, 6, 4)[:n_dir, 1, :3]
        nonneg = bool((np.asarray(arrays["point_radiance"]) >= 0).all() and (d >= 0).all()
                      and (np.asarray(lights.ambient) >= 0).all())
        groups = {}
        if scene.light_groups:
            groups = dict(point_end=np.asarray(arrays["point_group_end"], np.uint32),
                          dir_end=np.asarray(arrays["directional_group_end"], np.uint32),
                          group_ambient=np.asarray(arrays["ambient_group_radiance"])
                          * scene.material.k_a)
        return cls(directional=lights.directional, n_dir=n_dir,
                   ambient=np.asarray(lights.ambient, np.float64), nonnegative=nonneg, **groups)

    def floor_args(self, ctx, point_end=None) -> tuple:
        """kernels/cull.cl tile_floor's arguments (see :func:`_cull_level`'s ``floor``);
        ``point_end``: the groups' ends among the point records where they hold the light
        tree's representatives too (:class:`ExtendedLayout`), else the lights' own."""
        import pyopencl as cl

        ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
        dirs = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(self.directional, np.float32))

        def down(a):            # rounded down, so that the float32 floor never exceeds k_a·A
            return np.maximum(np.nextafter(np.asarray(a, np.float32), np.float32(-np.inf)), 0)

        G = self.n_groups
        ends = np.zeros((2, max(G, 1)), np.uint32)
        gamb = np.zeros((max(G, 1), 4), np.float32)
        if G:
            ends[0] = self.point_end if point_end is None else point_end
            ends[1] = self.dir_end
            gamb[:, :3] = down(self.group_ambient)
        pend = cl.Buffer(ctx, ro, hostbuf=ends[0].copy())
        dend = cl.Buffer(ctx, ro, hostbuf=ends[1].copy())
        gb = cl.Buffer(ctx, ro, hostbuf=gamb)
        return dirs, self.n_dir, float4(*down(self.ambient)), G, pend, dend, gb


#: Test-only: the factor the relative budget's floor is multiplied by (1: the proof).
#: tests/device/test_relative_budget.py raises it a few percent and sees the guarantee fail.
FLOOR_SCALE = 1.0


@dataclass(frozen=True)
class TreeInput:
    """What the light tree's cut needs besides the frame: the tree (a callable that
    builds it, or returns the one built before, only where a cut is tried), the
    specular model its bound uses, and the float64 point records (the fp64 path's)."""

    tree: Callable[[], LightTree | None]
    spec: SpecularModel
    point64: np.ndarray
    point_end: np.ndarray | None = None      # light groups: each group's end, else None


def _build_tile_lists(runtime, plan, frame, point_records, n_point, *, budget, k_d, S,
                      gbuf_buffer=None, maps_buffer=None, tree: TreeInput | None = None,
                      relative: RelativeInput | None = None):
    """Run kernels/cull.cl for one frame; return :class:`TileLists`, or None when
    culling cannot pay off (the lists would exceed ``MAX_LIST_ENTRIES``).

    Two levels: super-tiles of ``SUPER × SUPER`` tiles against every light with
    ``COARSE_SHARE`` of the budget, then each tile against its super-tile's list
    with the rest. ``gbuf_buffer`` and ``maps_buffer``: the frame's planes already
    on the device (the shading launch's), so they are not uploaded twice.

    ``relative``: ``budget`` is a fraction of each pixel's own value, per channel: each
    level's tiles get their share of it times a proven lower bound of their pixels'
    totals (kernels/cull.cl ``tile_floor``), and the tree's cut ``TREE_SHARE`` of it times
    each super-tile's floor.
    """
    import pyopencl as cl

    ctx = runtime.context
    lanes = max(plan.lanes, 1)
    sup = super_tiles(lanes)
    defines = {k: v for k, v in plan.defines.items() if k in CULL_DEFINES}
    prog = runtime.program("cull.cl", {**defines, "CULL_TILE": TILE, "CULL_SUPER": sup,
                                       "LANES": lanes})
    h, w = frame.shape
    # tiles_x padded to a multiple of the super-tile, so that a work-item's LANES
    # tiles share one super-tile; the padding tiles are empty
    tiles_x = -(-(-(-w // TILE)) // sup) * sup
    tiles_y = -(-h // TILE)
    super_x, super_y = tiles_x // sup, -(-tiles_y // sup)
    mf = cl.mem_flags
    ro = mf.READ_ONLY | mf.COPY_HOST_PTR
    g = gbuf_buffer if gbuf_buffer is not None else cl.Buffer(ctx, ro, hostbuf=frame.gbuf)
    mp = maps_buffer if maps_buffer is not None else cl.Buffer(ctx, ro, hostbuf=frame.maps)
    lb = cl.Buffer(ctx, ro, hostbuf=pack_cull_lights(point_records, n_point))
    # The tiles' bounds, then the super-tiles' merged from them (one pass over the frame).
    fine_tiles, e_fine = _tile_bounds(runtime, prog, frame, g, mp, k_d=k_d, S=S, tile_size=TILE,
                                      tiles_x=tiles_x, tiles_y=tiles_y, lanes=lanes)
    coarse_tiles, e_coarse = _merge_bounds(runtime, prog, fine_tiles, fine_tiles_x=tiles_x,
                                           fine_tiles_y=tiles_y, sup=sup, tiles_x=super_x,
                                           tiles_y=super_y, lanes=lanes, wait_for=[e_fine])
    floor = None if relative is None else relative.floor_args(ctx)
    if relative is not None and not relative.nonnegative:
        budget = 0.0
    coarse_budget = budget * COARSE_SHARE
    coarse = _cull_level(runtime, prog, coarse_tiles, [e_fine, e_coarse], lb, n_point,
                         budget=coarse_budget, tiles_x=super_x, tiles_y=super_y, lanes=lanes,
                         floor=floor)
    if coarse is None:
        return None
    c_ranges, c_lists, _, c_seconds, c_floors, c_unused = coarse
    extra = {} if c_floors is None else {"coarse_floors": c_floors}
    shaded = tile_of_pixels(frame.shape, lanes, tiles_x).reshape(-1)[~frame.background]
    shaded_tiles = np.unique(shaded)
    active = int(shaded_tiles.size)
    shared: dict = {}                # what every tree cut of this frame shares (_tree_cut)

    def fine_level(ranges_, lists_, lb_, n_lists, rest, floor_=floor):
        crb = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(ranges_))
        # the rest of the budget, rounded down so that the parts never sum past it
        fb = float(np.nextafter(np.float32(rest), np.float32(0)))
        return _cull_level(runtime, prog, fine_tiles, [], lb_, n_lists, budget=max(fb, 0.0),
                           tiles_x=tiles_x, tiles_y=tiles_y, lanes=lanes,
                           candidates=(crb, lists_), super_tiles=super_x * super_y, floor=floor_)

    def plain():
        return fine_level(c_ranges, c_lists, lb, n_point, budget - coarse_budget)

    spent = 0.0
    fine, share, took_tree, too_long = None, None, False, False
    ran_whole = False                # the whole pass without the tree ran (fine: its lists)

    def whole():
        nonlocal fine, ran_whole
        if not ran_whole:
            fine, ran_whole = plain(), True
        return fine

    probe = None
    if tree is None or budget <= 0:
        whole()
    else:
        probe = _probe(c_ranges, shaded, tiles_x=tiles_x, sup=sup, super_x=super_x)
        if probe is None:                 # the sample is every super-tile: the whole pass
            share = None if whole() is None else fine[2] / max(active * n_point, 1)
        else:
            p_ranges, p_active = probe
            sample = fine_level(p_ranges, c_lists, lb, n_point, budget - coarse_budget)
            # the sample's lists too long: the whole pass's (which hold them) are too
            too_long = sample is None
            share = None if too_long else sample[2] / max(p_active * n_point, 1)
            spent += 0.0 if too_long else sample[3]
        if share is not None and share <= TREE_ABOVE and whole() is None:
            share = None                  # culling alone keeps little, but too much for the lists
    # The light tree where culling alone keeps much (TREE_ABOVE of the lights on
    # average, or lists too long): the tiles cull again from the super-tiles' cuts,
    # and the shorter lists win. Elsewhere nothing changes (nor is the tree built).
    if tree is not None and budget > 0 and (share is None or share > TREE_ABOVE):
        # relative: each super-tile's share is ε·TREE_SHARE times its floor; and what the
        # super-tiles' culling left of its ε·COARSE_SHARE (where the tree is tried, that
        # culling drops little): a pixel's error stays within what the super-tile dropped
        # + its cut + its tile's culling ≤ ε (relative: times the floors)
        tree_budget = ((budget * TREE_SHARE + coarse_budget * c_unused)
                       * (1.0 if c_floors is None else c_floors))

        def super_cut(rows=None):
            return _tree_cut(runtime, tree, coarse_tiles, c_ranges, c_lists, point_records,
                             n_point, frame.origin, n_super=super_x * super_y,
                             budget=tree_budget, lanes=lanes, point_end=tree.point_end,
                             rows=rows, shared=shared)

        # long lists (BLOCK_ENTRIES): judged on the sample's super-tiles where there is
        # one (the probe's), so that the super-tiles' whole cut is made only where used
        cut, entries = None, None          # entries: the super-tiles' lists' mean length
        sample_rows = (None if probe is None or too_long
                       else np.flatnonzero(probe[0][:, 1] > 0))
        if sample_rows is not None and sample_rows.size:
            sampled = super_cut(sample_rows)
            entries = 0.0 if sampled is None else float(sampled[0][:, 1].mean())
            spent += 0.0 if sampled is None else sampled[-1]
        if entries is None or entries < BLOCK_ENTRIES:
            cut = super_cut()
            if entries is None:
                entries = 0.0 if cut is None else _mean_entries(
                    cut[0], shaded_tiles, tiles_x=tiles_x, sup=sup, super_x=super_x)
        long = entries >= BLOCK_ENTRIES
        block = None
        if long:
            # the cut again per block of BLOCK_TILES² tiles, with all the budget the
            # super-tiles' culling left (no tiles' culling after it)
            # (relative: times the floors; each tile's own, from its super-tile's list,
            # where higher than its super-tile's: a pixel's error is then at most
            # ε/4·T⁻_s (super-tile culling) + 3ε/4·T⁻_t (the cut) ≤ ε·its value)
            e_fine.wait()
            st = np.arange(tiles_x * tiles_y)
            st = (st // tiles_x // sup) * super_x + (st % tiles_x) // sup
            if c_floors is None:
                b_budget = (budget - coarse_budget + coarse_budget * c_unused)[st]
            else:
                t_floors, floor_s = _tile_floors(
                    runtime, prog, fine_tiles, lb, n_point, floor, c_ranges=c_ranges,
                    c_lists=c_lists, tiles_x=tiles_x, tiles_y=tiles_y,
                    super_tiles=super_x * super_y, lanes=lanes)
                spent += floor_s                     # counted with culling's seconds
                t_floors = np.maximum(t_floors, c_floors[..., st])
                b_budget = ((budget - coarse_budget) * t_floors
                            + coarse_budget * c_unused[st] * c_floors[..., st])
                # a tile with no shaded pixel (tile_floor gives it 0, so its super-tile's
                # floor) must not lower its block's or group's least: it takes its
                # super-tile's largest
                empty = np.ones(tiles_x * tiles_y, bool)
                empty[shaded_tiles] = False
                if empty.any():
                    top = np.full(b_budget.shape[:-1] + (super_x * super_y,), -np.inf)
                    np.maximum.at(np.moveaxis(top, -1, 0), st, np.moveaxis(b_budget, -1, 0))
                    b_budget = np.where(empty, top[..., st], b_budget)
            where = dict(tiles_x=tiles_x, tiles_y=tiles_y, sup=sup, super_x=super_x,
                         lanes=lanes, budget=b_budget)
            block = (_device_cut(runtime, tree, fine_tiles, c_ranges, c_lists, point_records,
                                 n_point, frame, shared, **where)
                     if DEVICE_CUT and entries < DEVICE_ENTRIES else None)
            if block is None:
                block = _block_cut(runtime, prog, tree, fine_tiles, e_fine, c_ranges, c_lists,
                                   point_records, n_point, frame, shared, **where)
            if block is not None:
                spent += 0.0 if cut is None else cut[-1]     # the super-tiles' cut, unused
                cut = block
            elif cut is None:                                # no block took a cluster
                cut = super_cut()
        if cut is not None:
            t_ranges, t_lists, records, records64, clusters, covered, layout, tree_s = cut
            if block is not None:
                # the tiles' lists are the blocks'; their floors those the cut's budget
                # rests on
                with_tree = (t_ranges, t_lists,
                             int(t_ranges[shaded_tiles, 1].sum(dtype=np.int64)), 0.0,
                             None if c_floors is None else t_floors, None)
            else:
                n_ext = len(records) // POINT_RECORD
                lb_ext = cl.Buffer(ctx, ro, hostbuf=pack_cull_lights(
                    records, n_ext, representative=layout.representative,
                    radius=cluster_radius(tree.tree(), layout, records, frame.origin)))
                floor_ext = (None if floor is None
                             else relative.floor_args(ctx, point_end=layout.point_end))
                with_tree = fine_level(t_ranges, t_lists, lb_ext, n_ext,
                                       budget - coarse_budget - budget * TREE_SHARE, floor_ext)
            # only the sample ran: the whole pass too where the tree's lists are not far
            # shorter than the sample foretells
            if not ran_whole and not too_long and (with_tree is None or with_tree[2]
                                                   * PROBE_MARGIN > share * active * n_point):
                whole()
            if with_tree is not None and (fine is None or with_tree[2] < fine[2]):
                if fine is not None:
                    spent += fine[3]                 # the pass without the tree, not used
                fine = with_tree
                t = tree.tree()
                extra.update(records=records, records64=records64, clusters=clusters,
                             record_source=layout.source,
                             point_end=None if tree.point_end is None else layout.point_end,
                             covered=covered, tree_seconds=tree_s, tree_nodes=t.n_nodes,
                             tree_lights=t.clusterable, tree_build_seconds=t.seconds,
                             tree_blocks=block is not None)
                took_tree = True
            else:
                spent += tree_s + (with_tree[3] if with_tree is not None else 0.0)
    if not took_tree and not too_long:
        whole()
    if fine is None:
        return None
    ranges, lists, kept, seconds, floors, _ = fine
    rb = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(ranges))
    return TileLists(ranges=rb, lights=lists, width=w, tiles_x=tiles_x, n_tiles=tiles_x * tiles_y,
                     kept=kept, n_point=n_point, seconds=c_seconds + seconds + spent,
                     active_tiles=active, floors=floors, **extra)


#: Where the super-tiles' cuts leave long lists, the tree's cut is made again per block
#: of BLOCK_TILES × BLOCK_TILES tiles (64×64 pixels), and the blocks' lists are the
#: tiles' own, with no tiles' culling after them. A node's bound shrinks with the box
#: it holds for: the proven cut of `clusters` at 65 536 lights keeps a median 15 176
#: entries over 256×256 pixels, 5 120 over 64×64 and 3 590 over 16×16 (absolute
#: 5·10⁻⁴, six sample pixels; 1 990 / 662 / 532 at 5·10⁻³). The host's cut costs about
#: 16× the super-tiles' there, so blocks of 4×4 tiles, not single tiles.
BLOCK_TILES = 4
#: Mean entries a list of the super-tiles' cuts must hold (over super-tiles with shaded
#: pixels) for the blocks' cut to be made. Measured on a 1920×256 crop of `clusters`
#: (Ice Lake, Intel's runtime, whole frames, super-tiles' path → blocks): 65 536 lights,
#: absolute 10⁻³: 5 040 → 2 154 ms; relative 10⁻²: 1 256 → 1 080 ms; 4 096 lights at
#: relative 10⁻³ 771 → 695 ms, but 10⁻² 373 → 524 ms and 10⁻¹ 202 → 451 ms, where the
#: lists are short (about 580 and 190 entries) and the blocks' cut (0.3 s) costs more
#: than it saves.
BLOCK_ENTRIES = 1000


def _mean_entries(ranges, tiles, *, tiles_x, sup, super_x) -> float:
    """The mean entries of the super-tiles' lists (``ranges``) over the super-tiles with
    shaded tiles (``tiles``: those tiles); 0 where none."""
    owner = np.unique((tiles // tiles_x // sup) * super_x + (tiles % tiles_x) // sup)
    return float(np.asarray(ranges)[owner, 1].mean()) if owner.size else 0.0


def _block_cut(runtime, prog, tin, fine_tiles, e_fine, c_ranges, c_lists, point_records,
               n_point, frame, shared, *, tiles_x, tiles_y, sup, super_x, lanes, budget):
    """The tree's cut per block of BLOCK_TILES² tiles (each from its super-tile's list and
    with the least budget of its tiles: ``budget`` per tile, and channel where relative); returns
    :func:`_tree_cut`'s tuple, its ranges per tile (a block's tiles share its list)."""
    blk = BLOCK_TILES
    assert sup % blk == 0, "a super-tile holds whole blocks"
    bx, by = tiles_x // blk, -(-tiles_y // blk)
    block_tiles, _ = _merge_bounds(runtime, prog, fine_tiles, fine_tiles_x=tiles_x,
                                   fine_tiles_y=tiles_y, sup=blk, tiles_x=bx, tiles_y=by,
                                   lanes=lanes, wait_for=[e_fine])
    per = sup // blk
    b = np.arange(bx * by)
    s_of_b = (b // bx // per) * super_x + (b % bx) // per
    t = np.arange(tiles_x * tiles_y)
    of = (t // tiles_x // blk) * bx + (t % tiles_x) // blk
    budget = np.asarray(budget, np.float64)
    b_budget = budget
    if budget.ndim:                        # each block's least of its tiles'
        b_budget = np.full(budget.shape[:-1] + (bx * by,), np.inf)
        np.minimum.at(np.moveaxis(b_budget, -1, 0), of, np.moveaxis(budget, -1, 0))
    cut = _tree_cut(runtime, tin, block_tiles, np.asarray(c_ranges)[s_of_b], c_lists,
                    point_records, n_point, frame.origin, n_super=bx * by, budget=b_budget,
                    lanes=lanes, point_end=tin.point_end, shared=shared)
    if cut is None:
        return None
    return (np.ascontiguousarray(cut[0][of]), *cut[1:])


def _device_cut(runtime, tin, fine_tiles, c_ranges, c_lists, point_records, n_point, frame,
                shared, *, tiles_x, tiles_y, sup, super_x, lanes, budget):
    """The tree's cut per group of CUT_GROUP² tiles on the device (kernels/node_bound.cl
    ``tile_cut``), each from its super-tile's culled lights and with its budget
    (``budget`` per tile, and channel where relative, as :func:`_block_cut`'s);
    :func:`_tree_cut`'s tuple, or None where the device cannot make it (no double,
    spots' cones, light groups) or no tile took a cluster. A tile whose group's cut
    would exceed the cap keeps its super-tile's list (exact)."""
    import pyopencl as cl

    tree = tin.tree()
    budget = np.asarray(budget, np.float64)
    if (tree is None or tin.point_end is not None or budget.ndim > 2
            or not DeviceNodeTerms.usable(runtime, tree)):
        return None
    t0 = time.perf_counter()
    n_tiles = tiles_x * tiles_y
    n_super = len(np.asarray(c_ranges))
    boxes = read_tile_boxes(runtime, fine_tiles, n_tiles, lanes)
    flat = np.zeros(max(c_lists.size // 4, 1), np.uint32)
    cl.enqueue_copy(runtime.queue, flat, c_lists).wait()
    if "layout" not in shared:
        layout = ExtendedLayout.of(tree, n_point, None)
        rep32, rep64 = representative_records(tree, frame.origin)
        shared.update(layout=layout, records=layout.records(point_records, rep32),
                      records64=layout.records(tin.point64, rep64),
                      nodes=DeviceNodeTerms(runtime, tree, tin.spec, frame.origin))
    nodes = shared["nodes"]
    if nodes is None:
        return None
    layout = shared["layout"]
    t = np.arange(n_tiles)
    t_super = (t // tiles_x // sup) * super_x + (t % tiles_x) // sup
    share = budget if budget.ndim else np.full(n_tiles, float(budget))
    share = np.broadcast_to(share.T if share.ndim == 2 else share[:, None], (n_tiles, 3))
    with np.errstate(divide="ignore"):
        scale = np.where(share > 0, (1 + 1e-12) / np.where(share > 0, share, 1.0), np.inf)
    # one cut per group of CUT_GROUP² tiles (inside one super-tile): their boxes merged,
    # the largest of their scales; each tile's list is its group's
    g = CUT_GROUP if sup % CUT_GROUP == 0 else 1
    groups_x = -(-tiles_x // g)
    group = (t // tiles_x // g) * groups_x + (t % tiles_x) // g
    n_groups = int(group.max()) + 1 if n_tiles else 0
    if g > 1:
        boxes, scale, t_super = _merge_groups(boxes, scale, t_super, group, n_groups)
    # each super-tile's culled lights: bits; those under no node: its extra records
    c_ranges = np.asarray(c_ranges, np.int64)
    words = -(-n_point // 32)
    kept = np.zeros((n_super, words * 32), bool)
    owner = np.repeat(np.arange(n_super), c_ranges[:, 1])
    idx = np.concatenate([flat[o:o + c] for o, c in c_ranges]) if n_super else flat[:0]
    kept[owner, idx] = True
    _, _, place = leaf_ranges(tree)
    outside = np.zeros(words * 32, bool)
    outside[np.flatnonzero(place < 0)] = True
    extra = [np.flatnonzero(kept[s] & outside) for s in range(n_super)]
    e_sizes = np.array([len(x) for x in extra], np.int64)
    e_ranges = np.stack([np.r_[0, np.cumsum(e_sizes)[:-1]], e_sizes], axis=1)
    extra = layout.light[np.concatenate(extra).astype(np.int64)] if e_sizes.sum() else []
    kept_bits = np.packbits(kept, axis=1, bitorder="little").view(np.uint32)
    # a cut of n lights holds at most n entries (each light once, alone or in a node);
    # the groups' places and the super-tiles' lists after them share one buffer
    room = CUT_LIST_BYTES // 4 - flat.size
    cap = int(min(CUT_CAP, max(n_point, 1), max(1024, room // max(n_groups, 1))))
    counts, _, lists = nodes.for_tiles(boxes).tile_cut(
        tree, scale, t_super, kept_bits, e_ranges, extra, layout.light, layout.node, cap=cap,
        reserve=flat.size)
    # a list too long for its place: the tile's super-tile's, copied after the cuts
    cl.enqueue_copy(runtime.queue, lists, c_lists, dst_offset=n_groups * cap * 4,
                    byte_count=flat.size * 4)
    counts = counts[group]
    over = counts[:, 0] == CUT_OVERFLOW
    ranges = np.stack([group * cap, counts[:, 0]], axis=1).astype(np.int64)
    ranges[over] = c_ranges[t_super[group][over]] + [n_groups * cap, 0]
    clusters = int(counts[~over, 1].sum(dtype=np.int64))
    if clusters == 0:
        return None
    return (ranges.astype(np.uint32), lists, shared["records"], shared["records64"], clusters,
            int(counts[~over, 2].sum(dtype=np.int64)), layout, time.perf_counter() - t0)


#: Whether, where the blocks' cut is made, it is made per group of CUT_GROUP² tiles on
#: the device where it can be (:func:`_device_cut`: double, no spots' cones, no light
#: groups), rather than per block on the host (:func:`_block_cut`), while the
#: super-tiles' lists hold fewer than DEVICE_ENTRIES entries on average. A group's cut
#: is coarser than its block's (a smaller box), but the device bounds ~2 nodes per
#: entry of every group where the host bounds them per block, and a group whose cut
#: exceeds the cap keeps its super-tile's whole list. Measured on whole 1080p frames at
#: 65 536 lights (Ice Lake, Intel's runtime, second frame; the super-tiles' sampled
#: mean in brackets), groups of 2² tiles, cap 16 384, against the host's blocks, one
#: run each (256 lights brute force: 0.53 s): `clusters` absolute 10⁻³ [17 087] 9.01 s
#: against 13.5 s, relative 10⁻² [1 756] 1.36 s against 1.83 s; `wide` relative 10⁻¹
#: [42 592] 62.7 s (most groups over the cap) against 57.0 s. Before node_bound.cl took
#: Intel's own vectoriser (isolate.IMPLICIT_VECTOR_KERNELS) the cut took twice as long:
#: `clusters` absolute 3·10⁻³ [7 623] 3.08 s against 4.23 s, relative 10⁻³ [15 983]
#: 10.5 s against 14.2 s; a cut per tile instead of 2² tiles: 12.5 s and 1.59 s, groups
#: of 4²: 9.85 s at absolute 10⁻³. With the cap at 65 536 (it was 16 384, where most of
#: `wide`'s groups passed it) the device's groups win on `wide` too: relative 10⁻¹
#: [41 826] 43.9 s against the blocks' 65.9 s, relative 10⁻² [57 652] 112 s against
#: 138 s (the blocks' first frame, which also builds the tree in ~1 s) (Ice Lake,
#: Intel's runtime, one run each, 2026-12-07).
DEVICE_CUT = True
DEVICE_ENTRIES = 60000
#: Tiles per side of a group that shares one cut from the device (1: a cut per tile):
#: its box holds its tiles', so the cut keeps somewhat more entries, for 1/CUT_GROUP²
#: of the cuts' work.
CUT_GROUP = 2
#: Most entries of a group's list from the device's cut (``tile_cut``: its place in the
#: lists buffer and its heap); a group whose cut needs more keeps its super-tile's list.
#: Fewer where the groups' places and the super-tiles' lists (copied after them, for the
#: groups that pass the cap) would pass CUT_LIST_BYTES in their one buffer (the culling
#: lists' own limit, MAX_LIST_ENTRIES; at most 65 536 at 1080p, 16 448 at 4K), 1 024 at
#: least; and never more than the lights: a cut of n lights holds at most n entries.
CUT_CAP = 65536
CUT_LIST_BYTES = 4 * MAX_LIST_ENTRIES


def _probe(c_ranges, shaded, *, tiles_x, sup, super_x):
    """The sample of super-tiles the tiles' pass without the tree runs on first
    (:data:`PROBE_EVERY`): their ranges, the others' emptied, and how many tiles with
    shaded pixels the sample holds; None where the sample would be every super-tile."""
    tiles = np.unique(shaded)
    owner = (tiles // tiles_x // sup) * super_x + (tiles % tiles_x) // sup
    supers = np.unique(owner)
    k = -(-len(supers) // PROBE_EVERY)
    if k >= len(supers):
        return None
    chosen = supers[((np.arange(k) + 0.5) * len(supers) / k).astype(np.int64)]
    ranges = np.array(c_ranges, copy=True)
    keep = np.zeros(len(ranges), bool)
    keep[chosen] = True
    ranges[~keep, 1] = 0
    return ranges, int(np.isin(owner, chosen).sum())


def _merge_groups(boxes: TileBoxes, scale, t_super, group, n_groups: int):
    """The tiles' boxes, scales and super-tiles merged per group (``group``: each
    tile's): boxes as kernels/cull.cl merge_bounds merges them (lo, nlo: min; hi, nhi,
    D, S: max; empty tiles' ±∞ drop out), the largest scale per channel."""
    def merge(x, ufunc, start):
        out = np.full((n_groups,) + x.shape[1:], start)
        ufunc.at(out, group, x)
        return out

    lo, hi = merge(boxes.lo, np.minimum, np.inf), merge(boxes.hi, np.maximum, -np.inf)
    nlo, nhi = merge(boxes.nlo, np.minimum, np.inf), merge(boxes.nhi, np.maximum, -np.inf)
    D, S = merge(boxes.D, np.maximum, -np.inf), merge(boxes.S, np.maximum, -np.inf)
    sup = np.zeros(n_groups, np.int64)
    sup[group] = t_super
    return (TileBoxes(lo=lo, hi=hi, nlo=nlo, nhi=nhi, D=D, S=S),
            merge(np.asarray(scale, np.float64), np.maximum, 0.0), sup)


def read_tile_boxes(runtime, tiles_buffer, n_tiles: int, lanes: int) -> TileBoxes:
    """The tile records of kernels/cull.cl tile_bounds / merge_bounds, read back."""
    import pyopencl as cl

    n_pad = _n_pad(n_tiles, lanes)
    planes = np.empty((T_PLANES, n_pad), np.float32)
    cl.enqueue_copy(runtime.queue, planes, tiles_buffer).wait()
    p = planes[:, :n_tiles].astype(np.float64)
    return TileBoxes(lo=p[0:3].T, hi=p[3:6].T, nlo=p[6:9].T, nhi=p[9:12].T, D=p[12:15].T,
                     S=p[15:18].T)


def _tree_cut(runtime, tin: TreeInput, coarse_tiles, c_ranges, c_lists, point_records,
              n_point, origin, *, n_super, budget, lanes, point_end=None, rows=None,
              shared=None):
    """The super-tiles' lists with the tree's clusters: per super-tile, the cut of
    :func:`~clphong.model.light_tree.choose_cut` (found by
    :func:`~clphong.model.light_tree.threshold_cut` in large trees: TOP_DOWN_NODES)
    within ``budget`` (a number, one per super-tile, or the relative budget's (3,
    super-tiles): one per channel and super-tile; 0 takes no cluster); its clusters
    replace the lights they stand for, and the culled lights stay out. None where
    no cluster fits. With light groups (``point_end``: each group's end), a group's
    clusters are its own lights' and use its own floors (``budget`` (G, 3, super-tiles)),
    and its representatives follow its lights (:class:`ExtendedLayout`).

    ``rows``: only these super-tiles (a sample); the ranges are theirs, in this order.
    ``shared``: a dict kept across a frame's cuts (its sample's, its super-tiles', its
    blocks'), which hold what depends only on the tree and the frame: the layout, the
    records and the nodes' device records, formed once.

    Returns (ranges, lists buffer, float32 records, float64 records, clusters,
    covered, layout, seconds).
    """
    import pyopencl as cl

    tree = tin.tree()
    if tree is None:
        return None
    t0 = time.perf_counter()
    boxes = read_tile_boxes(runtime, coarse_tiles, n_super, lanes)
    if rows is not None:
        boxes = TileBoxes(*(getattr(boxes, f)[rows] for f in ("lo", "hi", "nlo", "nhi", "D", "S")))
        c_ranges = np.asarray(c_ranges)[rows]
        budget = np.asarray(budget, np.float64)
        budget = budget[..., rows] if budget.ndim else budget
        n_super = len(rows)
    flat = np.zeros(max(c_lists.size // 4, 1), np.uint32)    # capacities ≥ counts
    cl.enqueue_copy(runtime.queue, flat, c_lists).wait()
    shared = {} if shared is None else shared
    if "layout" not in shared:
        layout = ExtendedLayout.of(tree, n_point, point_end)
        rep32, rep64 = representative_records(tree, origin)
        # the terms in double on the device where it can (kernels/node_bound.cl), else numpy
        shared.update(layout=layout, records=layout.records(point_records, rep32),
                      records64=layout.records(tin.point64, rep64),
                      nodes=(DeviceNodeTerms(runtime, tree, tin.spec, origin)
                             if NODE_TERMS_ON_DEVICE and DeviceNodeTerms.usable(runtime, tree)
                             else None))
    layout = shared["layout"]
    budget_ = np.asarray(budget, np.float64)
    device = None if shared["nodes"] is None else shared["nodes"].for_tiles(boxes)

    def terms(t, k, s0, pairs):
        if device is None:
            return None
        rows = s0 + (t if pairs else t[:, 0])
        if pairs:
            return device(rows, k)[:, None, :]
        kk = np.arange(tree.n_nodes) if k is None else np.asarray(k)
        return device(np.repeat(rows, len(kk)), np.tile(kk, len(rows))).reshape(
            len(rows), len(kk), 3)

    def bound(t, k, s0, pairs=False):
        """Each channel's bounds of super-tiles s0 + t with nodes k (all: None), in units
        of the budget: row by row (``pairs``), or t (T, 1) × every node."""
        part = TileBoxes(*(getattr(boxes, f)[s0 + (t if pairs else t[:, 0])]
                           for f in ("lo", "hi", "nlo", "nhi", "D", "S")))
        e = terms(t, k, s0, pairs)
        if not budget_.ndim:
            return cluster_bounds(tree, part, tin.spec, origin, k, pairs=pairs, terms=e,
                                  channels=True)
        # per super-tile and channel (and light group: a node's own group's floors):
        # each channel's bound in units of its budget (none: +inf, no cluster there)
        if budget_.ndim == 1:                        # (super-tiles,): the absolute budget
            share = budget_[s0 + t][..., None]
        elif budget_.ndim == 2:                      # (3, super-tiles)
            share = np.moveaxis(budget_[:, s0 + t], 0, -1)
        else:                                        # (G, 3, super-tiles)
            g = tree.group if k is None else tree.group[k]
            share = budget_[g, :, s0 + t]
        with np.errstate(divide="ignore"):
            scale = np.where(share > 0, (1 + 1e-12) / np.where(share > 0, share, 1.0), np.inf)
        if pairs:
            scale = scale[:, None]
        return cluster_bounds(tree, part, tin.spec, origin, k, pairs=pairs, channel_scale=scale,
                              terms=e, channels=True)

    limit = 1.0 if budget_.ndim else float(budget)     # the bounds' units
    kept_of = _KeptLights(tree, flat)
    new_lists, clusters, covered_n = [], 0, 0
    for s0 in range(0, n_super, TREE_CHUNK):
        s1 = min(s0 + TREE_CHUNK, n_super)
        if tree.n_nodes >= TOP_DOWN_NODES:
            # the same cut, bounding only the nodes it needs
            used, _ = threshold_cut(tree, lambda t, k, s0=s0: bound(t, k, s0, pairs=True),
                                    s1 - s0, limit, leaves=False)
        else:
            b = np.concatenate([bound(np.arange(a, min(a + DENSE_CHUNK, s1 - s0))[:, None], None, s0)
                                for a in range(0, s1 - s0, DENSE_CHUNK)])
            used, _ = choose_cut(tree, b, limit, leaves=False)
        for t in range(s1 - s0):
            nodes = np.flatnonzero(used[t])
            kept, covered = kept_of(c_ranges[s0 + t], nodes)
            clusters += nodes.size
            covered_n += covered
            new_lists.append(np.sort(np.concatenate([layout.light[kept], layout.node[nodes]])))
    if clusters == 0:
        return None
    sizes = np.array([len(x) for x in new_lists], np.int64)
    offsets = np.r_[0, np.cumsum(sizes)[:-1]]
    ranges = np.stack([offsets, sizes], axis=1).astype(np.uint32)
    lists = np.concatenate(new_lists).astype(np.uint32) if sizes.sum() else np.zeros(1, np.uint32)
    buf = cl.Buffer(runtime.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                    hostbuf=lists)
    return (ranges, buf, shared["records"], shared["records64"], clusters, covered_n, layout,
            time.perf_counter() - t0)


class _KeptLights:
    """A tile's lights after its cut: those of its super-tile's list (``flat``, a list
    per (offset, count) range) that no node of the cut stands for. The uncovered
    leaves are the gaps between the cut's runs in :func:`leaf_ranges`' order, so the
    work goes with what is kept, not with every light."""

    def __init__(self, tree: LightTree, flat: np.ndarray):
        self.start, self.end, place = leaf_ranges(tree)
        self.n_in = int(self.end.max()) if len(self.end) else 0
        inside = place >= 0
        self.leaf_at = np.empty(self.n_in, np.int64)
        self.leaf_at[place[inside]] = np.flatnonzero(inside)
        self.outside = np.flatnonzero(~inside)         # under no node: never covered
        self.n, self.flat, self.masks = tree.n_leaves, flat, {}

    def __call__(self, rng, nodes) -> tuple[np.ndarray, int]:
        """(the list's lights no node of ``nodes`` covers, how many lights they cover)."""
        o, c = int(rng[0]), int(rng[1])
        hit = self.masks.get((o, c))
        if hit is None:
            mask = np.zeros(self.n, bool)
            mask[self.flat[o:o + c]] = True
            hit = self.masks[(o, c)] = (mask, self.outside[mask[self.outside]])
        mask, outside = hit
        order = np.argsort(self.start[nodes], kind="stable")
        s, e = self.start[nodes][order], self.end[nodes][order]
        lo, hi = np.r_[0, e], np.r_[s, self.n_in]
        size = np.maximum(hi - lo, 0)
        gaps = size > 0
        lo, size = lo[gaps], size[gaps]
        first = np.r_[0, np.cumsum(size)[:-1]]
        pos = np.arange(int(size.sum())) + np.repeat(lo - first, size)
        leaves = self.leaf_at[pos]
        kept = np.concatenate([leaves[mask[leaves]], outside])
        return kept, int((e - s).sum())


@dataclass(frozen=True)
class ExtendedLayout:
    """The point records with the light tree's representatives: each light group's
    lights, then its representatives, so that the tile lists (in record order) stay
    in group order, as the kernels walk them (one group without light groups: the
    lights, then the representatives)."""

    light: np.ndarray        # (n,) uint32: each light's record
    node: np.ndarray         # (K,) uint32: each internal node's record
    point_end: np.ndarray    # (G,) uint32: each group's end among the records
    source: np.ndarray       # (n + K,): each record's light j, or n + k for node k

    @classmethod
    def of(cls, tree: LightTree, n_point: int, point_end=None) -> "ExtendedLayout":
        ends = (np.asarray(point_end, np.int64) if point_end is not None and len(point_end)
                else np.array([n_point], np.int64))
        K = tree.n_nodes
        group = np.asarray(tree.group, np.int64)
        reps = np.bincount(group, minlength=len(ends))
        before = np.r_[0, np.cumsum(reps)[:-1]]          # representatives before group g
        light = np.arange(n_point) + before[group_of(ends, n_point)]
        order = np.argsort(group, kind="stable")
        rank = np.empty(K, np.int64)
        rank[order] = np.arange(K) - before[group[order]]
        node = ends[group] + before[group] + rank
        source = np.empty(n_point + K, np.int64)
        source[light] = np.arange(n_point)
        source[node] = n_point + np.arange(K)
        return cls(light=light.astype(np.uint32), node=node.astype(np.uint32),
                   point_end=(ends + np.cumsum(reps)).astype(np.uint32), source=source)

    def records(self, lights: np.ndarray, representatives: np.ndarray) -> np.ndarray:
        """The records in this order, from the lights' (at least n) and the nodes'."""
        n = len(self.light)
        both = np.concatenate([lights[:n * POINT_RECORD], representatives])
        return both.reshape(-1, POINT_RECORD, 4)[self.source].reshape(-1, 4)

    @property
    def representative(self) -> np.ndarray:
        """(n + K,) bool: the records that are representatives."""
        return self.source >= len(self.light)


def read_tile_lists(runtime, lists: TileLists) -> list[np.ndarray]:
    """The kept light indices of every tile, read back (for tests and reports)."""
    import pyopencl as cl

    ranges = np.zeros((lists.n_tiles, 2), np.uint32)
    cl.enqueue_copy(runtime.queue, ranges, lists.ranges).wait()
    flat = np.zeros(max(lists.lights.size // 4, 1), np.uint32)
    cl.enqueue_copy(runtime.queue, flat, lists.lights).wait()
    return [flat[o:o + c].copy() for o, c in ranges]


def active_tiles(frame, lanes: int, tiles_x: int) -> int:
    """The tiles with a shaded pixel: those of the work-items (``lanes`` pixels each, a
    tile each, that of their first pixel, as :func:`tile_of_pixels`) holding one; a
    work-item at a time, not a pixel (1080p: 8 ms, where the pixels took 0.16 s)."""
    h, w = frame.shape
    bg = np.asarray(frame.background).reshape(-1)
    items = -(-bg.size // lanes)
    pad = np.ones(items * lanes, bool)
    pad[:bg.size] = bg
    first = np.flatnonzero(~pad.reshape(items, lanes).all(axis=1)) * lanes
    return int(np.unique((first // w // TILE) * tiles_x + (first % w) // TILE).size)


def tile_of_pixels(shape, lanes: int, tiles_x: int | None = None) -> np.ndarray:
    """The tile shading each pixel: that of its work-item's first pixel (cull.cl).

    ``tiles_x``: tiles per row as numbered by :func:`build_tile_lists` (padded);
    by default as there, for ``lanes``.
    """
    h, w = shape
    if tiles_x is None:
        sup = super_tiles(lanes)
        tiles_x = -(-(-(-w // TILE)) // sup) * sup
    q = np.arange(h * w)
    first = (q // lanes) * lanes
    y, x = first // w, first % w
    return ((y // TILE) * tiles_x + x // TILE).reshape(h, w)


@dataclass
class DirLists(ListedTiles):
    """Per-tile directional-light lists on the device (DIR_CULLING): each tile's lights
    that some normal of it may face, in light order (kernels/cull.cl dir_count)."""

    kept: int                 # Σ over tiles of the kept lights
    n_dir: int
    active_tiles: int
    seconds: float            # device time of the bounds and both list kernels

    @property
    def kept_fraction(self) -> float:
        """Mean fraction of the directional lights a tile with shaded pixels keeps."""
        return self.kept / max(self.active_tiles * self.n_dir, 1)


def build_dir_lists(runtime, plan, frame, directional, n_dir: int, *, k_d, S,
                    gbuf_buffer=None, maps_buffer=None) -> DirLists | None:
    """The directional lists of one frame (plan with DIR_CULLING): the tiles' bounds
    (``tile_bounds``), then per tile the count of lights it keeps, a prefix sum here,
    and the indices. ``directional``: the records as the shading kernel reads them.
    None where the lists would pass :data:`MAX_LIST_ENTRIES` (the frame is shaded
    with the plain loop)."""
    import pyopencl as cl

    with runtime.lock:
        ctx, queue = runtime.context, runtime.queue
        lanes = max(plan.lanes, 1)
        defines = {k: v for k, v in plan.defines.items() if k in CULL_DEFINES}
        prog = runtime.program("cull.cl", {**defines, "CULL_TILE": TILE,
                                           "CULL_SUPER": super_tiles(lanes), "LANES": lanes})
        h, w = frame.shape
        tiles_x, tiles_y = -(-w // TILE), -(-h // TILE)
        n_tiles = tiles_x * tiles_y
        n_pad = _n_pad(n_tiles, lanes)
        mf = cl.mem_flags
        ro = mf.READ_ONLY | mf.COPY_HOST_PTR
        g = gbuf_buffer if gbuf_buffer is not None else cl.Buffer(ctx, ro, hostbuf=frame.gbuf)
        mp = maps_buffer if maps_buffer is not None else cl.Buffer(ctx, ro, hostbuf=frame.maps)
        tiles, e0 = _tile_bounds(runtime, prog, frame, g, mp, k_d=k_d, S=S, tile_size=TILE,
                                 tiles_x=tiles_x, tiles_y=tiles_y, lanes=lanes)
        db = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(directional, np.float32))
        counts = np.zeros(n_pad, np.uint32)
        cb = cl.Buffer(ctx, mf.READ_WRITE, counts.nbytes)
        k1 = runtime.kernel(prog, "dir_count")
        k1.set_args(tiles, np.uint32(n_pad), np.uint32(n_tiles), db, np.uint32(n_dir), cb)
        e1 = cl.enqueue_nd_range_kernel(queue, k1, (n_pad,), (CULL_LOCAL,), wait_for=[e0])
        cl.enqueue_copy(queue, counts, cb, wait_for=[e1]).wait()
        total = int(counts[:n_tiles].sum(dtype=np.int64))
        if total > MAX_LIST_ENTRIES:          # uint32 offsets, and memory: the plain loop
            return None
        offsets = np.zeros(n_pad, np.uint32)
        offsets[1:] = np.cumsum(counts[:-1], dtype=np.uint64).astype(np.uint32)
        ob = cl.Buffer(ctx, ro, hostbuf=offsets)
        lists = cl.Buffer(ctx, mf.READ_WRITE, max(total, 1) * 4)
        k2 = runtime.kernel(prog, "dir_write")
        k2.set_args(tiles, np.uint32(n_pad), np.uint32(n_tiles), db, np.uint32(n_dir), ob, cb,
                    lists)
        e2 = cl.enqueue_nd_range_kernel(queue, k2, (n_pad,), (CULL_LOCAL,))
        e2.wait()
        ranges = np.stack([offsets[:n_tiles], counts[:n_tiles]], axis=1).astype(np.uint32)
        rb = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(ranges))
        active = active_tiles(frame, lanes, tiles_x)
        seconds = sum((e.profile.end - e.profile.start) * 1e-9 for e in (e0, e1, e2))
        return DirLists(ranges=rb, lights=lists, width=w, tiles_x=tiles_x, n_tiles=n_tiles,
                        kept=total, n_dir=n_dir, active_tiles=active, seconds=seconds)
