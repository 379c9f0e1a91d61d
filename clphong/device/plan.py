"""The shading plan: which kernel variant a scene needs, and why.

The plan turns a scene and the material maps a G-buffer carries into the ``-D``
defines of ``kernels/clphong.h``. Only what the scene uses is compiled in: no
specular code when ``k_s = 0`` and no k_s map, no point-light loop without point
lights, a constant view vector for an orthographic camera, Blinn's constant half
vector for directional lights seen by an orthographic camera, and map loads only
for the maps present, and a whole specular exponent raised by binary powering
instead of exp/log1p. ``print(plan)`` says what was chosen and why.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import SceneError
from ..core.geometry import split_hi_lo
from ..model.options import check_float_power, check_kernel, check_unroll
from ..model.scene import AOV_NAMES, MAP_KEYS
from .culling import TILE

#: Light sums longer than this use Neumaier compensation. The error of a naive
#: sum of n non-negative terms is at most (n−1)·u relative, 2u with
#: compensation; at n ≤ 4 the naive sum is already within 3u.
COMPENSATE_ABOVE = 4

#: Pixels per work-item, as explicit SIMD lanes (see kernels/clphong.h).
DEFAULT_LANES = 16

#: Directional lights from which the lane kernel reads per-tile lists of them
#: (DIR_CULLING: only the lights some normal of a tile may face; exact). An
#: environment becomes thousands; a scene's sun and sky lights, a few, for which
#: a list pass would cost more than it saves.
DIR_CULL_MIN = 64


#: The distance from which the float lanes loop's d²/16 may pass its cap 2¹²⁵ (d = 2⁶⁴·√2,
#: kernels/include/clphong.h RSQRT_LIGHT), with a margin for the roundings: a frame with
#: a point light that far from some pixel takes POINT_GUARD (frame.has_far_lights).
FAR_LIGHT = 2.0 ** 64


#: The smallest c0 (with c1, c2 ≥ 0) for which the float loop multiplies the weights by the
#: falloff (FALLOFF_ON_WEIGHTS): att ≤ (1 + 3u)/(c0·(1 − 4u)) < 1.5 there.
FALLOFF_ON_WEIGHTS_C0 = 0.7


#: The largest whole exponent k (h, or 4h for Blinn-Phong) raised by binary
#: powering (SPEC_INT_POW): at most 16 squarings and 15 products per light.
#: Blinn-Phong with h = 10⁴ (k = 4·10⁴) is inside.
INT_POW_MAX = 65536


def int_pow_multiplies(k: int) -> int:
    """Double multiplies of ``specular_power_cos`` (kernels/brdf.cl) for the
    whole exponent ``k``: one squaring per bit after the first, one product per
    set bit but bit 0 (s starts as x or 1)."""
    k = int(k)
    if k <= 0:
        return 0
    return k.bit_length() - 1 + bin(k).count("1") - (k & 1)


@dataclass(frozen=True)
class ShadingPlan:
    """The compile-time variant of the shading kernel for one scene."""

    defines: dict[str, int]
    reasons: tuple[tuple[str, str], ...]
    kernel: str = "lanes"
    n_point: int = 0
    n_spot: int = 0                 # of the n_point, the spots
    n_directional: int = 0
    n_ambient: int = 0
    maps: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default=())
    groups: tuple[str, ...] = ()
    aovs: tuple[str, ...] = ()

    @property
    def layers(self) -> tuple[str, ...]:
        """The names of the output's layers after the beauty, in plane order."""
        return self.groups + self.aovs

    @property
    def entry_file(self) -> str:
        return "shade.cl" if self.kernel == "lanes" else "shade_obvious.cl"

    @property
    def lanes(self) -> int:
        return self.defines.get("LANES", 1)

    def __str__(self) -> str:
        lines = [
            f"kernel: kernels/{self.entry_file} ({self.kernel}, {self.lanes} pixel(s) per work-item)",
            f"lights: {self.n_point} point"
            + (f" ({self.n_spot} of them spots)" if self.n_spot else "")
            + f", {self.n_directional} directional, {self.n_ambient} ambient",
            f"material maps: {', '.join(self.maps) if self.maps else 'none'}",
            "defines:",
        ]
        width = max(len(f"{k}={v}") for k, v in self.defines.items())
        why = dict(self.reasons)
        for k, v in self.defines.items():
            kv = f"{k}={v}"
            lines.append(f"  -D{kv:<{width}}  {why.get(k, '')}")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def _light_counts(scene) -> tuple[int, int, int, int]:
    """(point and spot, spot, directional, ambient) lights of a scene the kernels can shade:
    its environment lights resolved (else a SceneError)."""
    if scene.lights_of("environment"):
        raise SceneError(f"{scene.source}: an environment light reaches the kernels only as the "
                         "directional lights it is resolved into (clphong.io.envmap); resolve "
                         "the scene's environment lights before planning")
    return (len(scene.light_arrays["point_position"]),          # point and spot lights
            int(scene.light_arrays["point_is_spot"].sum()),
            len(scene.lights_of("directional")), len(scene.lights_of("ambient")))


def _material_defines(put, scene, maps, *, kernel, specular, n_dir) -> None:
    """The material's and the camera's defines (model, Fresnel, maps), through ``put``."""
    m = scene.material
    blinn = m.model == "blinn-phong"
    ortho = scene.camera.type == "orthographic"
    put("HAS_SPECULAR", specular,
        "k_s map present" if "k_s" in maps else f"material.k_s = {m.k_s:g}")
    fresnel = m.fresnel == "schlick" and specular
    if fresnel and kernel != "lanes":
        raise SceneError(f"{scene.source}: material.fresnel: the obvious kernel has no Fresnel "
                         "weight; use the lane kernel (the default)")
    put("FRESNEL", fresnel,
        "Schlick's W = f0 + (1 − f0)(1 − cos α)^5 in place of C_s, cos α = "
        + ("v·h per light" if blinn else "n·v per pixel") if fresnel
        else "no Fresnel weight: the constant k_s·C_s")
    if fresnel:
        hi, lo = split_hi_lo(m.f0)
        for c, h_, l_ in zip("RGB", hi.view("uint32"), lo.view("uint32")):
            put(f"FRESNEL_F0{c}", int(h_), f"f0 {c} as float32 bits (hi)")
            put(f"FRESNEL_F0{c}_LO", int(l_), f"f0 {c}'s float64 remainder as float32 bits")
    put("CAMERA_ORTHO", ortho, f"camera.type = {scene.camera.type!r}"
        + (": v is constant" if ortho else ": v = normalize(eye − P) per pixel"))
    put("BLINN_CONST_H", blinn and ortho and n_dir > 0 and specular,
        "Blinn + orthographic camera: each directional light's half vector is constant (host-computed)"
        if blinn and ortho else "needs Blinn-Phong with an orthographic camera")
    put("MAP_KD", "k_d" in maps, "per-pixel k_d map" if "k_d" in maps else "uniform k_d")
    put("MAP_KS", "k_s" in maps, "per-pixel k_s map" if "k_s" in maps else "uniform k_s")
    put("MAP_H", "h" in maps and specular, "per-pixel shininess map" if "h" in maps else "uniform h")
    put("MAP_CS", "specular_color" in maps and specular,
        "per-pixel specular colour map" if "specular_color" in maps else "uniform specular_color")
    cs = m.specular_color
    grey = specular and not fresnel and "specular_color" not in maps and cs[0] == cs[1] == cs[2]
    put("SPEC_GREY", grey, "k_s·C_s has equal channels: S·w_s once a light for all three" if grey
        else "needs a grey specular_color, no specular colour map and no Fresnel weight")


def _layer_defines(put, coverage, groups, aovs) -> None:
    """Coverage and the layers shaded beside the beauty, through ``put``."""
    put("COVERAGE", coverage, "partly covered pixels: outputs α-premultiplied, the beauty over "
                              "the background" if coverage else "no partly covered pixel")
    put("N_GROUPS", len(groups), f"light-group layers {', '.join(groups)} from the same pass"
        if groups else "no light groups")
    put("AOV_DIFFUSE", "diffuse" in aovs, "diffuse layer (with the ambient term)"
        if "diffuse" in aovs else "no diffuse layer")
    put("AOV_SPECULAR", "specular" in aovs, "specular layer" if "specular" in aovs
        else "no specular layer")


def _env_defines(put, scene, maps, *, kernel, groups, specular) -> None:
    """An environment as tables (kernels/include/envtable.h): their sizes and group."""
    tabled = scene.env_tables
    if not tabled:
        put("ENV_TABLE", 0, "no environment shaded from tables")
        return
    if kernel != "lanes" or len(tabled) > 1:
        raise SceneError(f"{scene.source}: the kernels read one environment's tables, in the lane "
                         "kernel; resolve the others into lights (clphong.io.envmap)")
    tables, group = tabled[0]
    if specular and (tables.specular is None or scene.material.model == "blinn-phong"
                     or "h" in maps):
        raise SceneError(f"{scene.source}: an environment's tables hold the Phong lobe of one "
                         "exponent, built with the specular term: not for Blinn-Phong, a "
                         "shininess map or tables built without it (clphong.io.envmap)")
    put("ENV_TABLE", 1, f"environment: {tables.describe()}")
    d = tables.diffuse
    put("ENV_D_ROWS", d.rows, f"the diffuse table E(n): {d.rows} latitudes pole to pole")
    put("ENV_D_COLS", d.cols, "and longitudes, cubic both ways")
    if specular:
        t = tables.specular
        put("ENV_S_ROWS", t.rows, f"the lobe table T(R), h = {t.power:g}: {t.rows} latitudes")
        put("ENV_S_COLS", t.cols, "and longitudes")
        put("ENV_S_OFFSET", (d.rows + 2) * d.cols, "the lobe table's first float4")
    put("ENV_GROUP", groups.index(group) if group is not None and group in groups else -1,
        f"in light group {group!r}" if group is not None and group in groups else "no light group")


def _sum_defines(put, scene, *, kernel, n_lights, n_point, sum_fp64, compensated,
                 fp64_directions=False, far_lights=False) -> None:
    """How the lights are summed, and whether the falloff depends on distance."""
    if kernel == "lanes":
        put("SUM_FP64", sum_fp64,
            f"{n_lights} lights summed in double, rounded once: error ≤ u + n·2⁻⁵³"
            if sum_fp64 else "no fast double on this device, or a float sum was asked for")
    put("COMPENSATED_SUM", compensated,
        f"{n_lights} lights summed: "
        + ("Neumaier summation keeps the sum's error at ~2u" if compensated
           else "in double (SUM_FP64)" if sum_fp64
           else f"naive float sum within {max(n_lights - 1, 0)}u"))
    c = scene.light_arrays["point_attenuation"]
    falloff = bool((c[:, 1:] != 0).any())
    put("HAS_ATTENUATION", falloff,
        "some point light has c1 or c2 ≠ 0: 1/(c0 + c1·d + c2·d²) per pixel" if falloff
        else ("every point light has c1 = c2 = 0: the falloff is the constant 1/c0"
              if n_point else "no point light"))
    c0_zero = bool((c[:, 0] == 0).any())
    # the float lanes loop's records carry 4c1 and 16c2 (frame.shading_records)
    quarter = kernel == "lanes" and not fp64_directions
    far = quarter and far_lights and n_point > 0
    put("POINT_GUARD", c0_zero or far,
        "some point light has c0 = 0: its falloff is infinite at d = 0, so a select "
        "gives it nothing there" if c0_zero else
        f"some point light may lie {FAR_LIGHT:.3g} or more from a pixel of this frame, "
        "beyond the float loop's cap on d²/16 (clphong.h RSQRT_LIGHT): selects give it "
        "nothing there (the error model's unbounded pixels)" if far else
        "no select for d = 0: l = 0 there, and every light's falloff is finite at 0 "
        "(c0 > 0)" + (", and no light of this frame reaches the float loop's cap on d²/16"
                      if quarter else "") + " (lights.h)" if n_point else "no point light")


def _lane_defines(put, scene, maps, *, n_point, n_dir, specular, blinn, fp64, fp64_directions,
                  int_pow, max_error, light_tile, sum_fp64, rsqrt_builtin=False,
                  light_unroll=0, rsqrt_native=False, relative=False, groups=(),
                  dir_lists=True) -> None:
    """The lane kernel's own defines (culling, the light loop, the number formats and the
    specular power), each with its reason, through ``put`` (see :func:`make_plan`)."""
    m = scene.material
    culling = max_error is not None and n_point > 0
    put("CULLING", culling,
        (f"--max-error {max_error:g} --relative: per-tile point-light lists, dropped lights "
         "sum to ≤ ε times a proven lower bound of each pixel's own value, per channel "
         "(kernels/cull.cl tile_floor)" if relative else
         f"--max-error budget ε = {max_error:g}: per-tile point-light lists, dropped lights "
         "sum to ≤ ε per pixel (kernels/cull.cl)") if culling
        else ("no point light to cull" if max_error is not None
              else "no --max-error budget: every light shades every pixel"))
    if culling:
        put("CULL_TILE", TILE, f"{TILE}x{TILE}-pixel culling tiles (clphong.device.culling.TILE)")
    dir_cull = n_dir >= DIR_CULL_MIN and not light_tile and dir_lists
    put("DIR_CULLING", dir_cull,
        f"{n_dir} directional lights: per-tile lists keep those some normal of the tile may "
        "face (n·l > 0); the others add exactly 0 there (kernels/cull.cl dir_count)"
        if dir_cull else f"fewer than {DIR_CULL_MIN} directional lights: no per-tile lists"
        if n_dir < DIR_CULL_MIN else "directional lights in one loop (the staged GPU loop "
        "reads every light)" if dir_lists else
        "directional lights in one loop: this frame's lists would pass MAX_LIST_ENTRIES")
    if dir_cull and not culling:
        put("CULL_TILE", TILE, f"{TILE}x{TILE}-pixel tiles of the directional lists")
    native_float = bool(rsqrt_native) and not fp64_directions
    fmt = "double" if fp64_directions else "float"
    # True: the builtin in both formats; else the formats (Runtime.rsqrt_builtin) it is taken in
    builtin = rsqrt_builtin is True or (not isinstance(rsqrt_builtin, bool) and fmt in rsqrt_builtin)
    put("RSQRT_BUILTIN", builtin,
        "1/√x by the OpenCL C builtin rsqrt (2 ulp by the specification): on this platform "
        "faster than clphong's inline steps"
        + (" (not used here: each 1/√x is in float, by RSQRT_NATIVE below)" if native_float
           else "")
        if builtin
        else f"1/√x in {fmt} by clphong's inline Newton steps (kernels/include/clphong.h), "
             "within the builtin's 2 ulp: PoCL calls the builtin out of line (GPUs: not "
             "measured with it)" if not rsqrt_builtin
        else f"1/√x in {fmt} by clphong's inline Newton steps (kernels/include/clphong.h): "
             f"this platform's builtin is taken in {' and '.join(rsqrt_builtin)} only "
             "(Runtime.rsqrt_builtin)")
    native = native_float
    put("RSQRT_NATIVE", native,
        "float 1/√x from native_rsqrt and one Newton step: the self-test measured it within "
        "2 ulp at this width, and this platform inlines it (its builtin is a call)" if native
        else "no native_rsqrt first guess" + (" (directions in double)" if rsqrt_native else ""))
    staged = light_tile and (n_dir > 0 or (n_point > 0 and not culling))
    put("LIGHT_TILE", light_tile if staged else 0,
        f"the work-group stages {light_tile} light records at a time through local memory "
        "(a GPU: one global read per light per work-group)" if staged
        else "each work-item reads the light records (a CPU: they stay in its L1)"
        if not light_tile else "no light loop to stage (the culled loop reads its lists)")
    check_unroll(light_unroll)
    put("LIGHT_UNROLL", light_unroll,
        f"the light loops take {light_unroll} lights an iteration, in order (an out-of-order "
        "CPU core overlaps their chains: docs/bench.md)" if light_unroll
        else "one light an iteration")
    put("DIRECTIONS_FP64", fp64_directions,
        "directions, n·l and δ in double: relative error a few u at grazing light and "
        "any shininess (docs/error-model.md)" if fp64_directions
        else "directions in float (devices without fast double): error grows near grazing "
             "light and with k")
    k = m.exponent
    whole = float(k).is_integer() and 0 <= k <= INT_POW_MAX
    in_float = int_pow == "float"
    check_float_power(int_pow, fp64_directions)
    use = specular and "h" not in maps and whole and (in_float or (fp64 and int_pow))
    exponent = f"k = {'4h' if blinn else 'h'} = {k:g}"
    cos_form = use and (fp64_directions or in_float) and (not blinn or int(k) % 2 == 0)
    kind = "float" if in_float else "double"
    put("SPEC_INT_POW", use,
        f"{exponent} is a whole number: binary powering in {kind}, "
        f"{int_pow_multiplies(int(k) // 2 if cos_form and blinn else k)} {kind} multiplies "
        "per light "
        "instead of exp(k·log1p(−δ)), and no rounding of k·log1p(−δ) (docs/error-model.md)" if use
        else ("no specular term" if not specular
              else "per-pixel shininess map: exp(k·log1p(−δ))" if "h" in maps
              else f"{exponent} is not a whole number ≤ {INT_POW_MAX}: exp(k·log1p(−δ))" if not whole
              else "no fast double on this device (cl_khr_fp64 at a measured quarter of the "
                   "float rate or more): exp(k·log1p(−δ))" if not fp64
              else "integer power turned off: exp(k·log1p(−δ))"))
    put("SPEC_K", int(k) if use else 0,
        f"the exponent K = {int(k)} compiled in: the binary powering unrolls, with no "
        "branch per bit (1.04-1.12x on the bench scene; one program per exponent)" if use
        else "no integer power")
    put("SPEC_COS", cos_form,
        (f"the power's base is (n·h)² = (n·l + n·v)²/|l + v|² in {kind}, raised to "
         f"K/2 = {int(k) // 2}: no square root and no |n − h|²/2 (docs/error-model.md)" if blinn
         else f"the power's base is r·v = 2(n·l)(n·v) − l·v in {kind}: no |r − v|²/2 "
              "(docs/error-model.md)")
        + (": on the fast path, all in float, within its own bound (docs/error-model.md)"
           if in_float else "") if cos_form
        else ("no integer power" if not use
              else "directions in float with the power in double: the base stays 1 − δ with "
                   "δ = |·|²/2, free of cancellation"
              if not fp64_directions
              else f"Blinn with an odd K = {int(k)}: 1 − δ with δ = |n − h|²/2"))
    put("POW_FP32", use and in_float,
        "the fast path: the integer power in float (relative error ~2k·u)" if use and in_float
        else "no integer power in float (only the fast path's)")
    weights = fp64_directions and sum_fp64
    put("WEIGHTS_FP64", weights,
        "D, S, weights, falloff and each light's L·att·(D·w_d + S·w_s) in double"
        + ("" if use or not specular else ", and exp(k·log1p(−δ)) too")
        + ", into the double sum: nothing rounded to float before the result" if weights
        else ("directions in float: weights in float" if not fp64_directions
              else "light sum in float: weights rounded to float"))
    # lights.h: the weights take the falloff and the sums form R·(D·att·w_d + S·att·w_s),
    # one product a light fewer than (att·R)·(D·w_d + S·w_s). In double always; in float
    # only where every falloff stays ≤ 1/0.7 (c0 ≥ 0.7, c1, c2 ≥ 0: p(d) ≥ c0), so that
    # D·att·w_d + S·att·w_s < 1.5·2¹²⁷ < FLT_MAX for D, S < 2¹²⁶ (clphong/io/nonfinite.py's
    # limits); a stronger falloff keeps att·R, which the scene and the near-field check
    # keep in float, and the weights ≤ 1.
    c = scene.light_arrays["point_attenuation"]
    tame = bool(np.all((c[:, 0] >= FALLOFF_ON_WEIGHTS_C0) & (c[:, 1] >= 0) & (c[:, 2] >= 0)))
    on_weights = n_point > 0 and (weights or (not fp64_directions and tame))
    put("FALLOFF_ON_WEIGHTS", on_weights,
        "the weights take each light's falloff: R·(D·att·w_d + S·att·w_s), one product a "
        "light fewer (lights.h)" + ("" if weights else f"; every c0 ≥ {FALLOFF_ON_WEIGHTS_C0:g} and "
                                    "c1, c2 ≥ 0, so att·w stays ≤ 1.5")
        if on_weights else
        "no point light" if not n_point else
        "double directions with float weights: att·R is formed in double and rounded once"
        if fp64_directions else
        f"some point light has c0 < {FALLOFF_ON_WEIGHTS_C0:g} or a negative c1 or c2: its falloff may "
        "pass 1.5, so att·R (kept in float by the scene) and weights ≤ 1, as D·att·w_d could overflow")


def make_plan(scene, maps=(), *, kernel: str = "lanes", lanes: int = DEFAULT_LANES,
              compensated: bool | None = None, fp64_directions: bool = False,
              max_error: float | None = None, has_fp64: bool | None = None,
              int_pow: bool | str = True, coverage: bool = False, groups: Sequence[str] = (),
              aovs: Sequence[str] = (), light_tile: int = 0,
              rsqrt_builtin: bool = False, light_unroll: int = 0,
              rsqrt_native: bool = False, relative: bool = False,
              dir_lists: bool = True, far_lights: bool = False) -> ShadingPlan:
    """Choose the kernel variant for ``scene`` and the material ``maps`` present.

    Parameters
    ----------
    scene : clphong.model.scene.Scene
    maps : iterable of str
        Names of the per-pixel material maps present (subset of ``clphong.model.scene.MAP_KEYS``, in any order).
    kernel : {"lanes", "obvious"}
        ``"lanes"``: LANES pixels per work-item in explicit vectors (the fast
        path). ``"obvious"``: one pixel per work-item with ``float3`` and
        ``pow()``, kept as the baseline that ``clphong bench`` measures against.
    lanes : {1, 4, 8, 16}
    compensated : bool, optional
        Force Neumaier summation in float on (True) or a naive float sum
        (False). By default (None) the lane kernel sums in double where the
        device has fast double (SUM_FP64, ``has_fp64``), and otherwise uses
        Neumaier above ``COMPENSATE_ABOVE`` lights.
    fp64_directions : bool
        Positions, directions, n·l and δ in double (lane kernel only); the
        caller decides from the device (``Runtime.has_fp64``).
    has_fp64 : bool, optional
        Whether the device runs double at a useful speed: ``cl_khr_fp64`` on a
        CPU (``Runtime.fast_fp64``); by default as ``fp64_directions``. The
        integer power needs it.
    int_pow : bool or "float"
        True (default): raise a whole uniform exponent k ≤ ``INT_POW_MAX`` by
        binary powering in double (SPEC_INT_POW) where ``has_fp64`` (the device's
        ``Runtime.fast_fp64``: double at a measured quarter of the float rate or more); False:
        always exp(k·log1p(−δ)) (to measure one against the other); "float":
        binary powering in float (POW_FP32, the "fast" path: float directions
        only, any device; relative error ~2k·u, docs/error-model.md).
    max_error : float, optional
        Culling budget ε in output radiance (``--max-error`` × reference
        white): with point lights, compile the per-tile light lists of
        ``kernels/cull.cl`` (CULLING=1). None: every light shades every pixel.
    relative : bool
        ``max_error`` is a fraction of each pixel's own value (``--relative``): the
        plan's reasons say so (the variant is the same).
    dir_lists : bool
        With :data:`DIR_CULL_MIN` directional lights or more: read them from per-tile
        lists (DIR_CULLING; False: the frame's lists would be too long).
    far_lights : bool
        Some point light may lie :data:`FAR_LIGHT` or more from a pixel of the frame
        (:func:`clphong.device.frame.has_far_lights`): on the float lanes path the plan
        turns POINT_GUARD on, whose selects give such a light nothing.
    coverage : bool
        The frame has partly covered pixels: gbuf plane 12 holds α and every
        output is α-premultiplied (COVERAGE).
    groups : sequence of str
        Light-group layers, in the order of the output planes (N_GROUPS).
    aovs : sequence of {"diffuse", "specular"}
        Component layers (AOV_DIFFUSE, AOV_SPECULAR).
    light_tile : int
        Lane kernel: 0, every work-item reads the light records itself (CPUs); T > 0,
        the work-group stages T records at a time through local memory (LIGHT_TILE,
        GPUs: ``Runtime.light_tile``), any T with any work-group size (each work-item
        loads every work-group-size-th float4). Bit-identical results either way.
    rsqrt_builtin : bool or collection of "float", "double"
        Lane kernel: 1/√x by the OpenCL C builtin rsqrt (RSQRT_BUILTIN: the
        specification's 2 ulp; ``Runtime.rsqrt_builtin``, Intel's CPU runtime) where the
        directions' format is one of these (True: both), else clphong's inline Newton
        steps (kernels/include/clphong.h).
    rsqrt_native : bool
        Lane kernel with float directions: the first guess of 1/√x is native_rsqrt, then
        one Newton step (RSQRT_NATIVE; ``Runtime.rsqrt_native``: where the self-test
        measured it within 2 ulp at this width).
    light_unroll : {0, 2, 4, 8}
        Lane kernel: U > 1, the light loops that each work-item walks itself take U
        lights an iteration, in order (LIGHT_UNROLL, ``Runtime.light_unroll``: Intel's
        CPU runtime); 0, one. Bit-identical results either way. The staged loop
        (``light_tile``) is not unrolled.

    The display output is not part of the plan: kernels/tonemap_apply.cl runs
    on the stored planes (clphong.device.display), so the shading kernel never
    depends on the tone-map operator, the view or the outputs.
    """
    check_kernel(kernel)
    m = scene.material
    maps = tuple(n for n in MAP_KEYS if n in set(maps))
    n_point, n_spot, n_dir, n_amb = _light_counts(scene)
    blinn = m.model == "blinn-phong"
    specular = m.k_s > 0 or "k_s" in maps
    fp64 = fp64_directions if has_fp64 is None else has_fp64
    sum_fp64 = kernel == "lanes" and fp64 and compensated is None
    if compensated is None:
        compensated = not sum_fp64 and n_point + n_dir > COMPENSATE_ABOVE
    d: dict[str, int] = {}
    r: list[tuple[str, str]] = []

    def put(name, value, why):
        d[name] = int(value)
        r.append((name, why))

    if kernel == "lanes":
        put("LANES", lanes, "explicit SIMD lanes across pixels, the widest the host rule allows "
            "and the self-test passed on this device (docs/platforms.md)")
    put("MODEL_BLINN", blinn, f"material.model = {m.model!r}")
    put("HAS_POINT", n_point > 0, f"{n_point} point light(s)")
    put("HAS_SPOT", n_spot > 0, f"{n_spot} of them spot light(s): the falloff times the cone "
        "factor t² (glTF KHR_lights_punctual)" if n_spot else "no spot light")
    put("HAS_DIRECTIONAL", n_dir > 0, f"{n_dir} directional light(s)")
    _material_defines(put, scene, maps, kernel=kernel, specular=specular, n_dir=n_dir)
    _sum_defines(put, scene, kernel=kernel, n_lights=n_point + n_dir, n_point=n_point,
                 sum_fp64=sum_fp64, compensated=compensated, fp64_directions=fp64_directions,
                 far_lights=far_lights)
    if kernel == "lanes":
        _lane_defines(put, scene, maps, n_point=n_point, n_dir=n_dir, specular=specular,
                      blinn=blinn, fp64=fp64, fp64_directions=fp64_directions, int_pow=int_pow,
                      max_error=max_error, light_tile=light_tile, sum_fp64=sum_fp64,
                      rsqrt_builtin=rsqrt_builtin, light_unroll=light_unroll,
                      rsqrt_native=rsqrt_native, relative=relative, groups=groups,
                      dir_lists=dir_lists)
    if kernel != "lanes" and (groups or aovs):
        raise SceneError(f"{scene.source}: the obvious kernel shades the beauty only; light groups "
                         "and AOV layers need the lane kernel")
    _layer_defines(put, coverage, groups, aovs)
    _env_defines(put, scene, maps, kernel=kernel, groups=groups, specular=specular)
    notes = []
    if not n_point and not n_dir:
        notes.append("no direct lights: only the ambient term is shaded")
    return ShadingPlan(defines=d, reasons=tuple(r), kernel=kernel, n_point=n_point, n_spot=n_spot,
                       n_directional=n_dir, n_ambient=n_amb, maps=maps, notes=tuple(notes),
                       groups=tuple(groups), aovs=tuple(a for a in AOV_NAMES if a in aovs))
