"""An environment conversion's probe pixels on the device (clphong.device.envprobe)."""

import numpy as np
import pytest
from conftest import record_calls

from clphong.device.envprobe import DeviceProbeShader
from clphong.model import environment as env
from clphong.model.scene import Material
from clphong.tools import samples

#: the accurate path's relative error target (docs/error-model.md), on pixels ≥ 1e-3 of
#: the largest, where the float32 output's own rounding is below it
ACCURATE = 5e-6

MATERIALS = {
    "blinn": Material(model="blinn-phong", k_a=0.3, k_d=0.7, k_s=0.2, h=32.0),
    "phong-schlick": Material(model="phong", k_a=0.1, k_d=0.6, k_s=0.4, h=9.5, fresnel="schlick",
                              f0=(0.04, 0.5, 0.9)),
    "grey-specular": Material(model="phong", k_a=0.0, k_d=0.5, k_s=0.5, h=64.0,
                              specular_color=(0.9, 0.4, 0.1)),
}


def _as_the_kernel_sees(n, v):
    """The probes as the device shades them: the float32 normal, made unit in float64;
    the view from the eye at 0 to the float32 position −v."""
    n32 = n.astype(np.float32).astype(np.float64)
    p32 = (-v).astype(np.float32).astype(np.float64)
    return (n32 / np.linalg.norm(n32, axis=1, keepdims=True),
            -p32 / np.linalg.norm(p32, axis=1, keepdims=True))


@pytest.mark.parametrize("name", sorted(MATERIALS))
@pytest.mark.parametrize("view", [None, (0.3, 0.4, -0.866)])
def test_probe_pixels_on_the_device_are_the_float64_ones(device, name, view):
    """The device's pixels against the float64 twin at the probes it shades, within the
    accurate path's target: every term (diffuse, Phong and Blinn lobes, Schlick's
    weight, a coloured C_s), ambient left out, and the probes of an orthographic view."""
    material = MATERIALS[name]
    rng = np.random.default_rng(3)
    l = rng.normal(size=(300, 3))
    l /= np.linalg.norm(l, axis=1, keepdims=True)
    rad = rng.random((300, 3)) * np.array([1.0, 0.5, 1e-3])     # one channel near 0
    n, v = env.probe_pairs(257, None if view is None else np.array(view) / np.linalg.norm(view))
    got = DeviceProbeShader(device)(n, v, l, rad, material)
    want = env.probe_pixels(*_as_the_kernel_sees(n, v), l, rad, material)
    assert got.shape == want.shape == (257, 3)
    big = want >= 1e-3 * want.max()
    assert big.sum() > 500
    err = np.abs(got - want)[big] / want[big]
    assert err.max() <= ACCURATE, err.max()


def test_a_conversion_with_the_device_probes_ends_where_the_numpy_one_does(device):
    """The search on device pixels: the same lights as on float64 numpy pixels (the two
    estimates differ by the probes' float32 rounding, measured 1e-4 of themselves on the
    sample sky)."""
    sky = samples.sky_envmap(128, 64)
    material = MATERIALS["blinn"]
    shade = DeviceProbeShader(device)
    for eps in (1e-2, 1e-3):
        a = env.environment_lights(sky, material, max_error=eps)
        b = env.environment_lights(sky, material, max_error=eps, shade=shade)
        assert b.count == a.count and b.met and a.met
        assert np.array_equal(a.l, b.l)
        assert abs(b.estimated_error - a.estimated_error) <= 1e-2 * a.estimated_error


def test_the_probes_walk_every_light_and_match_the_lists_bit_for_bit(device, monkeypatch):
    """The probes shade without directional lists (Renderer(dir_lists=False): a tile's
    probes face every way, so the lists cost more than they drop); the lists are exact,
    so the pixels are the same bits either way."""
    import clphong.device.envprobe as envprobe

    made = record_calls(monkeypatch, envprobe, "Renderer")
    rng = np.random.default_rng(5)
    l = rng.normal(size=(300, 3))                  # ≥ plan.DIR_CULL_MIN: lists would be made
    l /= np.linalg.norm(l, axis=1, keepdims=True)
    rad = rng.random((300, 3))
    n, v = env.probe_pairs(257, None)
    shader = DeviceProbeShader(device)
    got = shader(n, v, l, rad, MATERIALS["blinn"])
    r, frame = made[-1], shader._frame[1]
    assert r.shade(frame).plan.defines["DIR_CULLING"] == 0
    r.dir_lists = True
    with_lists = r.shade(frame)
    assert with_lists.plan.defines["DIR_CULLING"] == 1
    assert np.array_equal(np.asarray(with_lists.image, np.float64).reshape(-1, 3), got)


def test_the_probes_scene_of_columns_shades_the_bits_of_light_objects(device, monkeypatch):
    """The probes' scene is made from columns (scene.directional_scene), not a Light object
    a light: the kernel sees the same records, so the same bits as a Scene of Lights."""
    import clphong.device.envprobe as envprobe
    from clphong.device.renderer import Renderer
    from clphong.model.scene import Scene, directional_lights

    made = record_calls(monkeypatch, envprobe, "Renderer")
    rng = np.random.default_rng(6)
    l = rng.normal(size=(40, 3))
    l /= np.linalg.norm(l, axis=1, keepdims=True)
    rad = rng.random((40, 3))
    n, v = env.probe_pairs(64, None)
    shader = DeviceProbeShader(device)
    got = shader(n, v, l, rad, MATERIALS["phong-schlick"])
    r = made[-1]
    objects = Scene(camera=r.scene.camera, material=r.scene.material,
                    lights=directional_lights(l, rad), source="objects")
    want = Renderer(objects, device=device, path="accurate", light_tree=False,
                    dir_lists=False).shade(shader._frame[1])
    assert np.array_equal(np.asarray(want.image, np.float64).reshape(-1, 3), got)


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_probe_terms_on_the_device_are_the_float64_ones(device, name):
    """DeviceProbeShader.terms (a frame's probes: the diffuse and specular terms apart, the
    kernel's two layers of one launch) against numpy's probe_terms, within the accurate
    path's target; their sum is the white-albedo pixel."""
    material = MATERIALS[name]
    rng = np.random.default_rng(7)
    l = rng.normal(size=(200, 3))
    l /= np.linalg.norm(l, axis=1, keepdims=True)
    rad = rng.random((200, 3)) * np.array([1.0, 0.5, 1e-3])
    n, v = env.probe_pairs(129, None)
    shader = DeviceProbeShader(device)
    got = shader.terms(n, v, l, rad, material)
    want = env.probe_terms(*_as_the_kernel_sees(n, v), l, rad, material)
    assert got.shape == want.shape == (129, 6)
    big = want >= 1e-3 * want.max()
    assert (np.abs(got - want)[big] / want[big]).max() <= ACCURATE
    pixel = shader(n, v, l, rad, material)
    assert np.allclose(got[:, :3] + got[:, 3:], pixel, rtol=2 * ACCURATE, atol=0)
