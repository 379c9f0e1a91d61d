"""Tone-mapping operators: the kernels against their float64 twins, published values,
round trips, the fused shading path, and the operator registry.

Tolerance of every kernel comparison: clphong.reference.tonemap.error_bound, a running
error analysis of the kernel's own order of operations (OpenCL 1.2 ulp limits:
+−× 0.5 ulp, ÷ 2.5 ulp, log2/exp2 3 ulp, pow 16 ulp; literals' float32
rounding; each operand's error through the derivative; doubled for second-order
terms). See the module docstring of clphong/tonemap.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clphong.core.errors import ClphongError
from clphong.device.display import DisplayTransform, apply_display_transform
from clphong.model import tonemap as registry
from clphong.reference import tonemap

OPS = list(registry.OPERATORS)
U = tonemap.U


def hdr_inputs(seed=0, shape=(24, 40)):
    """Log-uniform scene-linear values over 1e-4..64 (20 stops), plus zeros and 0.18 grey."""
    rng = np.random.default_rng(seed)
    x = np.exp(rng.uniform(math.log(1e-4), math.log(64.0), shape + (3,))).astype(np.float32)
    x[0, :4] = 0.0
    x[1, :4] = 0.18
    return x


# ------------------------------------------------------------------ kernel vs reference

ACESCG_TO_REC709 = ((1.70505, -0.62179, -0.08326), (-0.13026, 1.14080, -0.01055),
                    (-0.02400, -0.12897, 1.15297))   # any 3x3 will do: the twin gets the same


@pytest.mark.parametrize("encoding", ["linear", "srgb"])
@pytest.mark.parametrize("op", OPS)
def test_operator_kernel_matches_float64_twin_within_error_model(op, encoding, device):
    x = hdr_inputs(OPS.index(op))
    for exposure, matrix in ((0.0, None), (0.7, ACESCG_TO_REC709)):
        dt = DisplayTransform(op, exposure=exposure, matrix=matrix, encoding=encoding)
        got = apply_display_transform(x, dt, device=device).astype(np.float64)
        ref, bound = dt.reference(x), dt.error_bound(x)
        err = np.abs(got - ref)
        worst = np.unravel_index(np.argmax(err - bound), err.shape)
        assert np.all(err <= bound), (op, encoding, exposure, worst, err[worst], bound[worst])
        if matrix is None:
            # The bound must stay useful: far below any visible difference (a 16-bit code is
            # 1.5e-5; AgX's 6th-order polynomial with coefficients up to 40 is the loosest at
            # ~2e-4). Not with the matrix: out-of-gamut colours cancel there (terms of 1.7·64
            # summing to ~0, then sRGB's slope 12.92), and the bound rightly grows.
            assert bound.max() < (3e-4 if op == "agx" else 3e-5)


@pytest.mark.parametrize("op", OPS)
def test_huge_and_infinite_inputs_saturate_to_white(op, device):
    """Far above its shoulder every operator shows its white (AgX's is 0.9985),
    the same from 2^24 up to float32's largest value and +inf (an overflowed sum):
    x² in the ACES fit and Hable overflowed above ~1.8e19 (inf/inf = NaN, shown
    black) before the clip to [0, 2^24]. The kernel holds its twin there too."""
    big = np.array([1e6, 2.0 ** 24, 1e19, 1e30, 3.4e38, np.inf], np.float32)
    x = np.stack([big, big, big], -1)[None]
    for exposure in (0.0, 70.0):
        dt = DisplayTransform(op, exposure=exposure, encoding="srgb")
        got = apply_display_transform(x, dt, device=device).astype(np.float64)
        assert np.all(got[0, 1:] == got[0, -1]) and np.all(got > 0.99), (op, exposure, got)
        with np.errstate(over="ignore", invalid="ignore"):
            ref, bound = dt.reference(x), dt.error_bound(x)
        assert np.all(np.abs(got - ref) <= bound), (op, exposure, got, ref)


@pytest.mark.parametrize("op,perturb", [
    ("hable", dict(white=11.2 * (1 + 1e-4))),
    ("reinhard-extended", dict(white=4.0 * (1 + 1e-4))),
    ("none", dict(exposure=1e-4)),
])
def test_error_model_detects_a_small_change_of_a_parameter(op, perturb, device):
    """The tolerance can fail: a 1e-4 relative change of a parameter exceeds it somewhere."""
    x = hdr_inputs(3)
    got = apply_display_transform(x, DisplayTransform(op, encoding="linear"), device=device).astype(np.float64)
    wrong = DisplayTransform(op, encoding="linear", **perturb)
    assert np.any(np.abs(got - wrong.reference(x)) > wrong.error_bound(x))


def test_exposure_is_stops_applied_before_tone_mapping(device):
    """exposure = 1 on x equals exposure 0 on 2x exactly (×2 is exact in float32)."""
    x = hdr_inputs(5)
    for op in OPS:
        a = apply_display_transform(x, DisplayTransform(op, exposure=1.0), device=device)
        b = apply_display_transform(2 * x, DisplayTransform(op, exposure=0.0), device=device)
        assert np.array_equal(a, b), op


# ------------------------------------------------------------------ published values

def _hable(x):
    # Hable 2010 (filmicworlds.com "Filmic Tonemapping Operators"): A..F, W = 11.2, bias 2.
    A, B, C, D, E, F = 0.15, 0.50, 0.10, 0.20, 0.02, 0.30
    return ((x * (A * x + C * B) + D * E) / (x * (A * x + B) + D * F)) - E / F


def _aces_hill_grey(g):
    # Hill's BakingLab ACES.hlsl: ACESInputMat, RRTAndODTFit
    # (v(v + 0.0245786) − 0.000090537)/(v(0.983729v + 0.432951) + 0.238081), ACESOutputMat.
    # (The input rows sum to 1, the output's third row to 0.99999: grey is not quite grey.)
    a_in = np.array([[0.59719, 0.35458, 0.04823], [0.07600, 0.90834, 0.01566],
                     [0.02840, 0.13383, 0.83777]])
    a_out = np.array([[1.60475, -0.53108, -0.07367], [-0.10208, 1.10813, -0.00605],
                      [-0.00327, -0.07276, 1.07602]])
    v = a_in @ np.full(3, g)
    v = (v * (v + 0.0245786) - 0.000090537) / (v * (0.983729 * v + 0.4329510) + 0.238081)
    return a_out @ v


def _agx_grey(g):
    # Wrensch's minimal AgX: the inset rows sum to 0.99999...; log2 encoding over
    # [−12.47393, 4.026069]; the published polynomial; the outset; pow 2.2.
    inset = np.array([[0.842479062253094, 0.0784335999999992, 0.0792237451477643],
                      [0.0423282422610123, 0.878468636469772, 0.0791661274605434],
                      [0.0423756549057051, 0.0784336, 0.879142973793104]])
    outset = np.array([[1.19687900512017, -0.0980208811401368, -0.0990297440797205],
                       [-0.0528968517574562, 1.15190312990417, -0.0989611768448433],
                       [-0.0529716355144438, -0.0980434501171241, 1.15107367264116]])
    v = inset @ np.full(3, g)
    v = (np.clip(np.log2(v), -12.47393, 4.026069) + 12.47393) / (4.026069 + 12.47393)
    v = (15.5 * v**6 - 40.14 * v**5 + 31.96 * v**4 - 6.868 * v**3 + 0.4298 * v**2
         + 0.1191 * v - 0.00232)
    return np.clip(outset @ v, 0, None) ** 2.2


def _pbr_neutral_grey(g):
    # Khronos PBR Neutral: min = g ≥ 0.08 → offset 0.04; peak g − 0.04 < 0.76 → no compression.
    return g - 0.04


PINS_AT_018 = {
    "none": 0.18,
    "reinhard": 0.18 / 1.18,                                    # Reinhard 2002 eq. 3
    "reinhard-extended": 0.18 * (1 + 0.18 / 16.0) / 1.18,       # eq. 4, L_white = 4
    "hable": _hable(2 * 0.18) / _hable(11.2),
    "aces-hill": None,                                          # per channel, below
    "agx": None,                                                # per channel, below
    "pbr-neutral": _pbr_neutral_grey(0.18),
}


@pytest.mark.parametrize("op", OPS)
def test_each_operator_at_middle_grey_matches_the_published_formula(op, device):
    x = np.full((1, 8, 3), 0.18, np.float32)
    dt = DisplayTransform(op, encoding="linear")
    got = apply_display_transform(x, dt, device=device)[0, 0].astype(np.float64)
    if op == "agx":
        want = _agx_grey(0.18)
    elif op == "aces-hill":
        want = _aces_hill_grey(0.18)
    else:
        want = np.full(3, PINS_AT_018[op])
    # 0.18 is not a float32: the pin is at 0.18, the kernel sees f32(0.18) (relative u);
    # the operators' slopes at grey are < 1.2, so that adds 1.2·0.18·u to the kernel's bound.
    tol = dt.error_bound(x)[0, 0] + 1.2 * 0.18 * U
    assert np.all(np.abs(got - want) <= tol), (got, want)


def test_pbr_neutral_is_the_identity_minus_the_fresnel_offset_below_compression(device):
    """Khronos PBR Neutral: output = input − offset while the offset peak < 0.8 − 0.04."""
    rng = np.random.default_rng(2)
    x = rng.uniform(0.0, 0.75, (16, 32, 3)).astype(np.float32)
    x64 = x.astype(np.float64)
    m = x64.min(axis=-1, keepdims=True)
    offset = np.where(m < 0.08, m - 6.25 * m * m, 0.04)
    want = x64 - offset
    assert want.max(axis=-1).max() < 0.76
    dt = DisplayTransform("pbr-neutral", encoding="linear")
    got = apply_display_transform(x, dt, device=device).astype(np.float64)
    assert np.all(np.abs(got - want) <= dt.error_bound(x))


def test_srgb_encoding_matches_colour_science(device):
    """The kernel's IEC 61966-2-1 encoding against colour.models.eotf_inverse_sRGB."""
    colour = pytest.importorskip("colour")
    x = np.concatenate([np.linspace(0, 1, 4000), np.geomspace(1e-6, 0.01, 4000)])
    x = x.astype(np.float32).reshape(80, 100, 1).repeat(3, axis=2)
    dt = DisplayTransform("none", encoding="srgb")
    want = colour.models.eotf_inverse_sRGB(x.astype(np.float64))
    # The twin is the published formula: equal to colour-science to float64 rounding.
    assert np.max(np.abs(dt.reference(x) - want)) < 1e-12
    got = apply_display_transform(x, dt, device=device).astype(np.float64)
    assert np.all(np.abs(got - want) <= dt.error_bound(x))


# ------------------------------------------------------------------ round trips

ROUND_TRIP_RANGE = {"none": (0.01, 0.99), "reinhard": (1e-3, 40.0),
                    "reinhard-extended": (1e-3, 3.5), "hable": (1e-2, 5.0),
                    "aces-hill": (2e-2, 3.0), "agx": (2e-3, 8.0), "pbr-neutral": (1e-3, 6.0)}


def _jacobian(op, x, h=1e-6):
    """∂y_i/∂x_j of the float64 twin by central differences (relative error ~h²)."""
    J = np.empty(x.shape + (3,))
    for j in range(3):
        d = np.zeros(3)
        d[j] = 1.0
        step = h * np.maximum(x[..., j:j + 1], 1e-3)
        J[..., :, j] = (tonemap.reference(x + step * d, op) - tonemap.reference(x - step * d, op)) / (2 * step)
    return J


@pytest.mark.parametrize("op", OPS)
def test_round_trip_through_the_inverse(op, device):
    """kernel(x) then the float64 inverse gives x back, within the kernel's error through J⁻¹."""
    lo, hi = ROUND_TRIP_RANGE[op]
    rng = np.random.default_rng(OPS.index(op) + 10)
    x = np.exp(rng.uniform(math.log(max(lo, 1e-6)), math.log(hi), (12, 16, 3))).astype(np.float32)
    dt = DisplayTransform(op, encoding="linear")
    y = apply_display_transform(x, dt, device=device).astype(np.float64)
    ref = dt.reference(x)
    ok = np.all((ref > 1e-3) & (ref < 1 - 1e-3), axis=-1)     # not clipped: invertible there
    assert ok.sum() > 50
    back = tonemap.inverse(y[ok], op)
    x64 = x.astype(np.float64)[ok]
    if op == "none":
        tol = dt.error_bound(x)[ok]
    else:
        Jinv = np.linalg.inv(_jacobian(op, x64))
        # |Δx| ≤ |J⁻¹|·|Δy|; ×1.01 covers the finite-difference Jacobian's error.
        tol = 1.01 * np.einsum("...ij,...j->...i", np.abs(Jinv), dt.error_bound(x)[ok])
    assert np.all(np.abs(back - x64) <= tol + 1e-12 * x64), op
    # And the inverse really is one: reference(inverse(reference(x))) = reference(x).
    assert np.allclose(tonemap.reference(tonemap.inverse(ref[ok], op), op), ref[ok], atol=1e-12)


# ------------------------------------------------------------------ on the shading output, on the device

@pytest.mark.parametrize("kernel", ["lanes", "obvious"])
def test_display_output_equals_the_twin_of_the_shaded_frame(kernel, device):
    from conftest import make_scene, random_gbuffer, random_lights

    from clphong.device.renderer import Renderer

    rng = np.random.default_rng(4)
    scene = make_scene(random_lights(rng, 3, 1), background=(0.5, 2.0, 0.0))
    gb = random_gbuffer(rng, 16, 24)
    r = Renderer(scene, kernel=kernel, device=device)
    plain = r.render(gb).image
    dt = DisplayTransform("agx", exposure=1.5)
    result = r.render(gb, display=dt)
    rgb, shown = result.image, result.display
    assert result.bands == 1
    assert "DISPLAY_OUT" not in result.plan.defines          # the shading plan has no display
    assert np.array_equal(rgb, plain)                         # scene-linear output unchanged
    assert np.all(np.abs(shown - dt.reference(rgb)) <= dt.error_bound(rgb))


@pytest.mark.parametrize("kernel", ["lanes", "obvious"])
def test_display_changes_never_rebuild_the_shading_kernel(kernel, device):
    """Operator, exposure, encoding and straight alpha are the display program's
    (kernels/tonemap_apply.cl); the shading program is built once for them all."""
    from conftest import make_scene, random_gbuffer, random_lights

    from clphong.device.renderer import Renderer
    from clphong.device.selection import get_runtime

    rng = np.random.default_rng(5)
    scene = make_scene(random_lights(rng, 3, 1))
    gb = random_gbuffer(rng, 8, 16)
    r = Renderer(scene, kernel=kernel, device=device)
    rt = get_runtime(device)

    def shading_programs():
        return {k for k in rt._programs if k[0] != "tonemap_apply.cl"}

    r.render(gb)
    before = shading_programs()
    first = None
    for dt in (DisplayTransform("agx", exposure=1.5), DisplayTransform("hable", exposure=-1),
               DisplayTransform("none", encoding="linear"), DisplayTransform("reinhard")):
        result = r.render(gb, display=dt)
        assert np.all(np.abs(result.display - dt.reference(result.image))
                      <= dt.error_bound(result.image))
        first = result.image if first is None else first
        assert np.array_equal(result.image, first)
    assert shading_programs() == before


def test_display_defines_name_the_operator():
    dt = DisplayTransform("hable", exposure=-1)
    assert dt.defines()["DISPLAY_OUT"] == 1 and dt.defines()["TONEMAP"] == 3
    assert "hable" in dt.reasons()["TONEMAP"] and "-1 EV" in dt.reasons()["TONEMAP"]


# ------------------------------------------------------------------ registry

def test_bad_operator_name_lists_the_valid_ones():
    with pytest.raises(registry.ToneMapError) as info:
        registry.operator("reinhart")
    msg = str(info.value)
    assert "'reinhart'" in msg and all(repr(n) in msg for n in OPS) and "did you mean" in msg
    assert isinstance(info.value, ClphongError) and isinstance(info.value, ValueError)
    assert "\n" not in msg


def test_aliases_and_ids_are_those_of_the_kernel():
    assert registry.operator("Uncharted2").name == "hable"
    assert registry.operator("ACES").name == "aces-hill"
    assert registry.operator("pbr_neutral").name == "pbr-neutral"
    src = (__import__("clphong.device.runtime").device.runtime.kernel_dir() / "include" / "tonemap.h").read_text()
    for op in registry.OPERATORS.values():
        define = "TONEMAP_" + op.name.upper().replace("-", "_")
        assert f"#define {define}" in src and src.split(f"#define {define}")[1].split()[0] == str(op.id)


@pytest.mark.parametrize("white", [0.0, -1.0, math.inf, math.nan])
def test_bad_white_point_is_an_error(white):
    with pytest.raises(registry.ToneMapError, match="white point"):
        DisplayTransform("reinhard-extended", white=white)


def test_reference_handles_nd_input_and_zero():
    x = np.zeros((2, 3, 4, 3))
    for op in OPS:
        y = tonemap.reference(x, op)
        assert y.shape == x.shape and np.all(np.isfinite(y))


def test_bench_output_errors_table_covers_every_operator_within_its_bound():
    """python -m clphong.tools.output_bench --errors: every operator, both encodings, over
    1e-4 ... 1e6 (the shoulders and far above them), none beyond its bound."""
    from clphong.tools.output_bench import operator_errors, operator_errors_table

    rows = operator_errors(width=96, height=16, seed=1)
    assert {(r["operator"], r["encoding"]) for r in rows} == \
        {(op, enc) for op in OPS for enc in ("linear", "srgb")}
    assert all(r["beyond_bound"] == 0 and r["max_err_over_bound"] <= 1.0 for r in rows), rows
    assert len(operator_errors_table(rows).splitlines()) == 2 + len(rows)
