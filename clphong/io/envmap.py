"""Environment maps: reading them, and resolving environment lights into directional ones.

An ``[[light]]`` of ``type = "environment"`` names a latitude-longitude map
(``file``, any format OpenImageIO reads: EXR, Radiance HDR, ...) in OpenEXR's
orientation (:mod:`clphong.model.environment`). The kernels shade point, spot,
directional and ambient lights only, so before a scene reaches them
:func:`resolve_environment` replaces each environment light by the directional
lights of :func:`clphong.model.environment.environment_lights` (same group),
within the relative error ``max_error`` (``--env-error``).

Bad input is one line naming the scene key (:class:`~clphong.core.errors.SceneError`)::

    scene.toml: light[3].file: sky.exr: no such file
    scene.toml: light[3].file: sky.exr: cannot read: <OpenImageIO's reason>
    scene.toml: light[3].file: sky.exr: 1000 x 600 texels: a latitude-longitude map is 2:1 ...
    scene.toml: light[3].file: sky.exr: 12 NaN texel(s), 3 with Inf, 40 negative; ...
    scene.toml: light[3].file: sky.exr: reading a 65536x32768 map needs about ... of memory ...
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import threading
import time
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..core.cache import Store
from ..core.errors import SceneError, clean_line
from ..core.files import not_regular
from ..core.geometry import across, view_vector
from ..core.memory import require_memory
from ..model import env_table as _env_table
from ..model import environment as _environment
from ..model import scene as _scene
from ..model.environment import DEFAULT_ENV_ERROR, EnvironmentLights, environment_lights
from ..model.scene import Light, Scene, SceneWarning
from .exrfile import oiio_message

__all__ = ["read_envmap", "resolve_environment", "ResolvedScene", "ENV_BYTES_PER_TEXEL",
           "ENV_FIXED_BYTES", "environment_key", "directional_lights", "frame_pairs", "FrameSource",
           "check_environment_maps"]

#: Peak bytes per texel of reading a map and resolving it (the float32 read, its
#: float64 energy, the directions, the tree's summed-area table and its node
#: slices), plus :data:`ENV_FIXED_BYTES` for the probes' work arrays and the
#: lights: above tracemalloc's peak (132 bytes a texel at 1024 x 512 and 1e-2;
#: tests/io/test_envmap.py checks the model at two sizes).
ENV_BYTES_PER_TEXEL = 160
ENV_FIXED_BYTES = 64 << 20


def environment_key(scene: Scene, index: int) -> str:
    """``"<scene file>: light[i].file"``: where messages about light ``index``'s map point."""
    return f"{scene.source}: light[{index}].file"


def _fail(where: str, name: str, problem: str):
    raise SceneError(clean_line(f"{where}: {name}: {problem}"))


def read_envmap(path, where: str = "environment", nonfinite: str = "error") -> np.ndarray:
    """Read a latitude-longitude map as (H, W, 3) float32 radiance, checked.

    Parameters
    ----------
    path : str or os.PathLike
        The map: any format OpenImageIO reads. Its R, G, B channels (by name),
        else a single channel as grey, else its first three.
    where : str
        What the messages name first (the scene key, :func:`environment_key`).
    nonfinite : {"error", "background", "pass"}
        NaN or Inf texels (``--nonfinite``): "error" refuses the map; "background"
        takes them as 0 (no light from there), with a warning giving the counts; "pass"
        is refused too (one NaN texel would make every pixel NaN), naming the others.

    An alpha channel is ignored: a lat-long map is radiance from every direction, and
    OpenEXR's RGBA sky has α = 1 everywhere. A map whose texels are all 0 warns: it adds
    no light.

    Raises
    ------
    SceneError
        One line ``"<where>: <file>: <problem>"``: missing, not a regular file,
        unreadable, not 2:1 (W = 2H, H >= 2), more than memory allows, or
        holding NaN, Inf (unless ``nonfinite="background"``) or negative texels (with
        their counts).
    """
    name = os.fspath(path)
    if not os.path.exists(name):
        _fail(where, name, "no such file")
    kind = not_regular(name)
    if kind is not None:       # a FIFO would block OpenImageIO forever, a device read forever
        _fail(where, name, f"cannot read: it is {kind}; give a regular file (an EXR or HDR map)")
    inp = oiio.ImageInput.open(name)
    if inp is None:
        _fail(where, name, f"cannot read: {oiio_message(oiio.geterror) or 'unknown error'}")
    try:
        spec = inp.spec()
        W, H, C = int(spec.width), int(spec.height), int(spec.nchannels)
        if W != 2 * H or H < 2:
            _fail(where, name, f"{W} x {H} texels: a latitude-longitude map is 2:1 (width = 2 x "
                               "height, at least 4 x 2); resample it, e.g. oiiotool IN --resize "
                               f"{2 * max(H, 2)}x{max(H, 2)} -o OUT")
        names = list(spec.channelnames)
        if all(c in names for c in "RGB"):
            pick = [names.index(c) for c in "RGB"]
        elif C == 1 or "Y" in names:
            pick = [names.index("Y") if "Y" in names else 0] * 3
        elif C >= 3:
            pick = [0, 1, 2]
        else:
            _fail(where, name, f"has channels {names}: give R, G, B (or one grey channel)")
        lo, hi = min(pick), max(pick) + 1
        require_memory(4 * W * H * (hi - lo) + ENV_BYTES_PER_TEXEL * W * H + ENV_FIXED_BYTES,
                       f"{where}: {name}: reading and resolving a {W}x{H} environment map",
                       SceneError, "use a smaller map (e.g. oiiotool IN --resize 2048x1024 -o OUT) "
                       "or set CLPHONG_MAX_MEMORY if you know there is more memory")
        pix = inp.read_image(0, 0, lo, hi, oiio.TypeDesc("float"))
        if pix is None:
            _fail(where, name, f"cannot read: {oiio_message(inp.geterror) or 'unknown error'}")
    finally:
        inp.close()
    pix = np.asarray(pix, np.float32).reshape(H, W, hi - lo)
    L = np.ascontiguousarray(pix[:, :, [p - lo for p in pick]])
    bad = _texel_problems(L)
    if bad and nonfinite == "background" and not (L < 0).any():
        hidden = ~np.isfinite(L).all(axis=-1)
        L[hidden] = 0.0
        warnings.warn(SceneWarning(clean_line(
            f"{where}: {name}: {bad} taken as 0, no light from there (--nonfinite background)")))
    elif bad:
        cure = ("repair or clamp it, e.g. oiiotool IN --fixnan black --clamp:min=0 -o OUT"
                + ("; --nonfinite background takes NaN/Inf texels as 0" if nonfinite != "background"
                   and not (L < 0).any() else ""))
        _fail(where, name, bad + f"; an environment map holds finite radiance >= 0 ({cure})")
    if not L.any():
        warnings.warn(SceneWarning(clean_line(
            f"{where}: {name}: every texel is 0: the environment adds no light")))
    return L


def _texel_problems(L: np.ndarray) -> str:
    """"12 NaN texel(s), 3 with Inf, 40 negative" (texels with any such channel), or ""."""
    nan = int(np.isnan(L).any(axis=-1).sum())
    inf = int(np.isinf(L).any(axis=-1).sum())
    with np.errstate(invalid="ignore"):
        neg = int((L < 0).any(axis=-1).sum())
    parts = []
    if nan:
        parts.append(f"{nan} NaN texel(s)")
    if inf:
        parts.append(f"{inf} {'with Inf' if parts else 'texel(s) with Inf'}")
    if neg:
        parts.append(f"{neg} {'negative' if parts else 'negative texel(s)'}")
    return ", ".join(parts)


@dataclass(frozen=True)
class ResolvedScene:
    """A scene whose environment lights are directional lights now.

    Attributes
    ----------
    scene : Scene
        The scene the kernels can shade: each environment light replaced, in
        place, by its directional lights (same group).
    environments : tuple of (int, EnvironmentLights)
        Per environment light shaded as lights: its index in the original ``lights`` and
        the conversion (light count, estimated error, time).
    tables : tuple of (int, EnvTables)
        Per environment light shaded from tables (``scene.env_tables``): its index and
        its tables.
    paths : tuple of (int, str, str)
        Per environment light: its index, its path (``"tables"`` or ``"lights"``) and why.
    fallback : (Scene, ndarray) or None
        Where the tables' bound fails on some of the frame's pixels (at most MIXED_SHARE of
        them): the scene with the tabled environment as directional lights (estimated on
        those pixels), and their flat indices, for
        :meth:`clphong.device.renderer.Renderer.with_fallback`.
    """

    scene: Scene
    environments: tuple = ()
    tables: tuple = ()
    paths: tuple = ()
    fallback: tuple | None = None


#: A frame whose tables' bound fails on more than this share of its shaded pixels takes the
#: lights everywhere; below it, those pixels alone take them (a second launch on them).
MIXED_SHARE = 0.5


_LOCK = threading.Lock()
_CACHE: dict = {}
#: Conversions kept per process (each holds its lights only, not the map).
_CACHE_SIZE = 8


#: Conversions kept on disk (``environment/`` in clphong's cache folder, least recently
#: used removed first): a 1024 x 512 map at 1e-3 is ~10,800 lights, about 0.5 MB.
DISK_KEEP = 64
_DISK = Store("environment", ".npz", DISK_KEEP)
#: Called with one line when a conversion runs (not a cache hit) and is still running after
#: NOTICE_AFTER_S, then with its progress at most once a second; None (the library's
#: default) is silent, the CLI writes to a terminal (runtime.notice_on_tty).
conversion_notice = None
NOTICE_AFTER_S = 1.0


def _disk_key(digest: str, light: Light, material, view, max_error: float, policy: str,
              shader: str = "numpy") -> str:
    """The disk cache's name of a conversion: the map file's SHA-256, what the conversion
    depends on (rotation, intensity, the material, an orthographic view, the target, the
    probe shader's key), and the code that converts (a changed model/environment.py
    converts again)."""
    h = hashlib.sha256()
    for part in (digest, repr(float(light.rotation)), repr(float(light.intensity)), repr(material),
                 None if view is None else tuple(map(float, view)), repr(float(max_error)),
                 policy, _code_digest(), *(() if shader == "numpy" else (shader,))):
        h.update(str(part).encode() + b"\0")
    return h.hexdigest()[:40]


_CODE: list = []


def _code_digest() -> str:
    if not _CODE:
        _CODE.append(hashlib.sha256(Path(_environment.__file__).read_bytes()).hexdigest())
    return _CODE[0]


def _file_digest(name: str) -> str | None:
    """SHA-256 of the map file's bytes (a 1024 x 512 EXR: ~10 ms), or None if unreadable
    (read_envmap then says why)."""
    h = hashlib.sha256()
    try:
        with open(name, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return None
    return h.hexdigest()


def _load(path: Path):
    """(a conversion, the map's warnings) from the disk cache, or None (missing, damaged,
    another layout)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            return (EnvironmentLights(l=np.array(z["l"], np.float64),
                                      radiance=np.array(z["radiance"], np.float64), seconds=0.0,
                                      **{k: meta[k] for k in ("texels", "estimated_error",
                                                              "max_error", "met", "probes")}),
                    tuple(str(n) for n in meta.get("notes", ())))
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile):
        return None


def _save(name: str, r: EnvironmentLights, notes=()) -> None:
    meta = json.dumps({"texels": r.texels, "estimated_error": r.estimated_error,
                       "max_error": r.max_error, "met": r.met, "probes": r.probes,
                       "seconds": r.seconds, "notes": list(notes)})
    _DISK.put(name, lambda f: np.savez(f, l=r.l, radiance=r.radiance, meta=np.array(meta)))


_TABLES: dict = {}
#: Tables kept on disk (``envtables/``): a 1024 x 512 map's at 1e-3 are about 0.5 MB.
_TABLE_DISK = Store("envtables", ".npz", DISK_KEEP)
_TABLE_CODE: list = []


def _table_material(material):
    """What a map's tables depend on in the material: the lobe's exponent, if any."""
    return float(material.exponent) if material.k_s > 0 else None


def _tables(light: Light, where: str, material, max_error: float, nonfinite: str = "error"):
    """``light``'s map as tables (:func:`clphong.model.env_table.environment_tables`), or the
    one-line reason it cannot be tabled; cached per process and on disk (``envtables/``:
    the map's content, rotation, intensity, the lobe's exponent, the target and the
    table code)."""
    name = light.file
    policy = "background" if nonfinite == "background" else "error"
    spec = _table_material(material)
    try:
        st = os.stat(name)
        key = (os.path.realpath(name), st.st_ino, st.st_size, st.st_mtime_ns, light.rotation,
               light.intensity, spec, max_error, policy)
    except OSError:
        key = None
    disk: list = []

    def find():
        disk.append(_table_disk_key(light, spec, max_error, policy) if key is not None else None)
        found = None if disk[0] is None else _TABLE_DISK.get(disk[0])
        return None if found is None else _load_tables(found)

    def make():
        L, notes = _read_noting(name, where, nonfinite)
        progress = _Progress(f"{where}: {name}", "into tables")
        try:
            made = _env_table.environment_tables(
                L, material, rotation=light.rotation, intensity=light.intensity,
                max_error=max_error,
                on_size=lambda t: progress.say(
                    ("the diffuse" if t.power == 1 else f"the lobe (h = {t.power:g})")
                    + f" table, {t.rows} x {t.cols}, estimated error {t.estimate:.2g}"))
        except _env_table.TablesUnfit as e:
            made = str(e)
        if disk[0] is not None:
            _save_tables(disk[0], made, notes)
        return made, notes

    return _cached(_TABLES, key, find, make)


def _read_noting(name: str, where: str, nonfinite: str):
    """(the map, the one-line warnings reading it gave): a cache keeps them with what it
    made of the map, and says them again on every hit."""
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always", SceneWarning)
        L = read_envmap(name, where, nonfinite)
    return L, tuple(str(w.message) for w in said if issubclass(w.category, SceneWarning))


def _cached(cache: dict, key, find, make):
    """What a map becomes (its lights, or its tables), through the process's ``cache``
    (``key``; None: the file cannot be read, read_envmap will say why), then ``find()``
    (the disk's), then ``make()``; each gives (result, the map's warnings). The warnings
    are said again on every hit."""
    with _LOCK:
        hit = cache.get(key) if key is not None else None
    if hit is None:
        hit = find()
        if hit is None:
            hit = make()
        if key is not None:
            with _LOCK:
                if len(cache) >= _CACHE_SIZE:
                    cache.pop(next(iter(cache)))
                cache[key] = hit
    made, notes = hit
    for note in notes:                    # the map's warnings, from the cache too
        warnings.warn(SceneWarning(note))
    return made


def _table_disk_key(light: Light, spec, max_error: float, policy: str) -> str | None:
    """The disk cache's name of a map's tables: its content's SHA-256, the light's rotation
    and intensity, the lobe's exponent, the target, the policy and the table code; None
    where the file cannot be read."""
    digest = _file_digest(light.file)
    if digest is None:
        return None
    if not _TABLE_CODE:
        _TABLE_CODE.append(hashlib.sha256(Path(_env_table.__file__).read_bytes()).hexdigest())
    h = hashlib.sha256()
    for part in (digest, repr(float(light.rotation)), repr(float(light.intensity)),
                 repr(spec), repr(float(max_error)), policy, _TABLE_CODE[0], _code_digest()):
        h.update(str(part).encode() + b"\0")
    return h.hexdigest()[:40]


def _tabled_before(light: Light, material, max_error: float, nonfinite: str) -> bool:
    """Whether this very map (its content) became tables under these settings in an earlier
    run, so that it reads without error (the disk cache holds them, not a refusal)."""
    policy = "background" if nonfinite == "background" else "error"
    key = _table_disk_key(light, _table_material(material), max_error, policy)
    found = None if key is None else _TABLE_DISK.get(key)
    got = None if found is None else _load_tables(found)
    return got is not None and not isinstance(got[0], str)


_TABLE_ARRAYS = ("sun_l", "sun_radiance", "power", "radiance_max", "lune", "diffuse_floor")


def _save_tables(name: str, t, notes=()) -> None:
    if isinstance(t, str):
        meta = {"unfit": t, "notes": list(notes)}
        _TABLE_DISK.put(name, lambda f: np.savez(f, meta=np.array(json.dumps(meta))))
        return
    sp = t.specular
    meta = {"unfit": None, "notes": list(notes), "rotation": t.rotation, "estimate": t.estimate,
            "texel_angle": t.texel_angle,
            "max_error": t.max_error, "seconds": t.seconds,
            "diffuse": [t.diffuse.power, t.diffuse.estimate, t.diffuse.seconds],
            "specular": None if sp is None else [sp.power, sp.estimate, sp.seconds]}
    arrays = {k: getattr(t, k) for k in _TABLE_ARRAYS}
    arrays["diffuse"] = t.diffuse.values
    if sp is not None:
        arrays["specular"] = sp.values
    _TABLE_DISK.put(name, lambda f: np.savez(f, meta=np.array(json.dumps(meta)), **arrays))


def _load_tables(path: Path):
    """(tables or the reason there are none, the map's warnings) from the disk cache, or
    None (missing, damaged, another layout)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            notes = tuple(str(n) for n in meta.get("notes", ()))
            if meta["unfit"] is not None:
                return str(meta["unfit"]), notes

            def table(key, values):
                power, estimate, _ = meta[key]
                return _env_table.CubicTable(np.array(values, np.float64), float(power),
                                             float(estimate), 0.0)

            sp = None if meta["specular"] is None else table("specular", z["specular"])
            arrays = {k: np.array(z[k], np.float64) for k in _TABLE_ARRAYS}
            return (_env_table.EnvTables(diffuse=table("diffuse", z["diffuse"]), specular=sp,
                                         rotation=float(meta["rotation"]),
                                         texel_angle=float(meta["texel_angle"]),
                                         estimate=float(meta["estimate"]),
                                         max_error=float(meta["max_error"]), seconds=0.0,
                                         **arrays), notes)
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile):
        return None


def _table_refusal(material, pairs) -> str | None:
    """Why an environment of this frame takes lights rather than tables, or None."""
    if not isinstance(pairs, FrameSource):
        return ("its estimate covers every normal and view (--env-probes all, or no frame): the "
                "tables' horizon bound is held on a frame's own pixels")
    return _env_table.table_refusal(material, tuple(getattr(pairs.gbuffer, "maps", None) or {}))


class _Progress:
    """The conversion's notices (:data:`conversion_notice`): after NOTICE_AFTER_S, one
    line saying what runs, then the search's progress at most once a second."""

    def __init__(self, what: str, into: str = "into directional lights"):
        self.what, self.into, self.t0, self.last = what, into, time.perf_counter(), None

    def __call__(self, k: int, e: float) -> None:
        self.say(f"{k:,} lights, estimated error {e:.2g}")

    def say(self, progress: str) -> None:
        hook = conversion_notice
        now = time.perf_counter()
        if hook is None or now - self.t0 < NOTICE_AFTER_S:
            return
        if self.last is None:
            hook(f"clphong: converting {self.what} {self.into} (first use; "
                 "cached afterwards)\u2026")
        if self.last is None or now - self.last >= 1.0:
            hook(f"clphong: {self.what}: {progress} ({now - self.t0:.0f} s)")
            self.last = now


def frame_pixels(camera, gbuffer, material=None):
    """Every shaded pixel of a frame as the kernels see it, float32: (idx, pixels, n, v,
    diffuse, specular) with ``idx`` the pixels' flat indices (a slice where every pixel
    is shaded), ``pixels(idx, dtype)`` forming (n, v, diffuse weight, specular weight)
    of any of them, and those four for all of them (:func:`frame_pairs`). None where no
    pixel is shaded."""
    # the cells are chosen on float32 copies of every shaded pixel; the probes chosen
    # are then formed in float64 from the stored float32 values
    N = np.asarray(gbuffer.normal, np.float32).reshape(-1, 3)
    P = np.asarray(gbuffer.position, np.float32).reshape(-1, 3)
    with np.errstate(invalid="ignore", over="ignore"):
        ok = (across(np.logical_and, np.isfinite(N)) & across(np.logical_and, np.isfinite(P))
              & across(np.logical_or, N != 0))
    cov = getattr(gbuffer, "coverage", None)
    if cov is not None:
        ok &= np.asarray(cov).reshape(-1) > 0
    if not ok.any():
        return None
    # every pixel shaded (a full frame): slices, not gathers
    shaded = slice(None) if ok.all() else np.flatnonzero(ok)
    view = view_vector(camera)
    eye = None if view is not None else np.asarray(camera.position, np.float64)

    def pixels(idx, dtype):
        """(n, v, diffuse weight, specular weight) of the shaded pixels ``idx``."""
        n = N[idx].astype(dtype, copy=isinstance(idx, slice))      # changed in place below
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            n /= across(np.maximum, np.abs(n))[:, None]     # no overflow or underflow in n·n
            n /= np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
            if view is not None:
                v = np.broadcast_to((view / np.linalg.norm(view)).astype(dtype), n.shape)
            else:
                d = eye.astype(dtype) - P[idx].astype(dtype, copy=False)
                dd = np.sqrt(np.einsum("ij,ij->i", d, d))
                v = np.where(dd[:, None] > 0, d / np.where(dd > 0, dd, 1)[:, None], n)
        return (n, v, *_probe_weights(gbuffer, idx, material, dtype))

    n32, v32, d32, s32 = pixels(shaded, np.float32)
    # a NaN or Inf albedo or map is the non-finite policy's (a background pixel, a refused
    # frame, or NaN passed through): not a probe, and not in the ranges; nor an eye far
    # beyond float32 (the kernel's NaN too)
    ok = (across(np.logical_and, np.isfinite(v32)) & across(np.logical_and, np.isfinite(d32))
          & across(np.logical_and, np.isfinite(s32)))
    if not ok.all():
        shaded = (np.arange(len(N)) if isinstance(shaded, slice) else shaded)[ok]
        n32, v32, d32, s32 = n32[ok], v32[ok], d32[ok], s32[ok]
        if not len(shaded):
            return None
    return shaded, pixels, n32, v32, d32, s32


def frame_pairs(camera, gbuffer, count: int = _environment.PROBES, material=None, pixels=None):
    """The probes of a frame (:func:`clphong.model.environment.frame_probe_indices`): the unit
    normals, views and albedos of ``gbuffer``'s shaded pixels (a non-zero, finite normal
    and position, coverage above 0) under ``camera`` (perspective or orthographic: a
    metadata camera resolved for this frame first), as the kernels see them: v =
    (eye − P)/|eye − P|, or n where P is the eye. None where no pixel is shaded.

    Returns a :class:`clphong.model.environment.FrameProbes`: the probes with their
    pixels' weights of the two terms, and the frame's ranges of those weights, which
    the estimate holds (:func:`clphong.model.environment.frame_error`). Per-pixel k_d,
    k_s and specular-colour maps enter the weights against ``material``'s uniform
    values. Pixels with a NaN or Inf albedo or map are left out. A shininess map does
    not: the probes keep the material's h. The albedo is as stored (before an
    ``albedo_space`` conversion). ``pixels``: :func:`frame_pixels`'s result, if made."""
    got = frame_pixels(camera, gbuffer, material) if pixels is None else pixels
    if got is None:
        return None
    shaded, pixels, n32, v32, d32, s32 = got
    a32 = _environment.folded_albedo(d32, s32)
    pick = _environment.frame_probe_indices(n32, v32, count, albedo=a32)
    if not isinstance(shaded, slice):
        pick = shaded[pick]
    n, v, dw, sw = pixels(pick, np.float64)
    def per_channel(reduce, a):          # a column at a time (a reduce over axis 0 is slow)
        return np.array([reduce(a[:, c]) for c in range(3)], np.float64)

    return _environment.FrameProbes(
        n=n, v=v, diffuse=dw, specular=sw, low=per_channel(np.min, a32),
        high=per_channel(np.max, a32), diffuse_max=per_channel(np.max, d32),
        specular_max=per_channel(np.max, s32))


def _probe_weights(gbuffer, idx, material, dtype) -> tuple[np.ndarray, np.ndarray]:
    """The pixels ``idx``'s weights of the material's two terms, (P, 3) each: a pixel is
    diffuse·(k_d·diffuse) + specular·(k_s·C_s·specular), diffuse the stored albedo × k_d
    map / k_d, specular k_s map / k_s × specular-colour map / C_s (1 without maps)."""
    albedo = np.maximum(np.asarray(gbuffer.albedo).reshape(-1, 3)[idx].astype(dtype, copy=False), 0)
    spec = np.ones_like(albedo)
    maps = getattr(gbuffer, "maps", None) or {}
    if material is None or not maps:
        return albedo, spec

    def plane(name):
        return np.asarray(maps[name]).reshape(-1)[idx].astype(dtype)

    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if "k_d" in maps and material.k_d > 0:
            albedo = albedo * np.maximum(plane("k_d") / dtype(material.k_d), 0)[:, None]
        if "k_s" in maps and material.k_s > 0:
            spec = spec * np.maximum(plane("k_s") / dtype(material.k_s), 0)[:, None]
        if "specular_color" in maps:
            cs = np.asarray(material.specular_color, np.float64)
            spec = spec * np.maximum(np.asarray(maps["specular_color"]).reshape(-1, 3)[idx]
                                     .astype(dtype) / np.where(cs > 0, cs, 1.0).astype(dtype), 0)
    return albedo, spec


class FrameSource:
    """A frame's probes, made only when a conversion runs: :meth:`digest` names them from
    the frame's bytes (its normals, positions, albedos, coverage and material maps),
    the camera and the material, so a conversion found in a cache costs a hash of the
    frame (0.09 s at 1920 × 1080), not the probes' choice (0.42 s);
    :meth:`probes` is :func:`frame_pairs` (None: no shaded pixel)."""

    def __init__(self, camera, gbuffer, material, count: int = _environment.PROBES):
        self.camera, self.gbuffer, self.material, self.count = camera, gbuffer, material, count
        self._digest = None
        self._probes: list = []
        self._pixels: list = []
        self._shaded = None

    def digest(self) -> str:
        if self._digest is None:
            h = hashlib.blake2b(digest_size=32)
            g = self.gbuffer
            cam = self.camera
            h.update(repr((cam.type, getattr(cam, "position", None), getattr(cam, "direction", None),
                           self.count, self.material, FRAME_PROBES_VERSION)).encode())
            maps = getattr(g, "maps", None) or {}
            cov = getattr(g, "coverage", None)
            for name, a in (("normal", g.normal), ("position", g.position), ("albedo", g.albedo),
                            ("coverage", cov), *sorted(maps.items())):
                if a is None:
                    continue
                a = np.ascontiguousarray(a)
                h.update(f"{name} {a.dtype.str} {a.shape}".encode())
                h.update(memoryview(a).cast("B"))
            self._digest = h.hexdigest()
        return self._digest

    def pixels(self):
        """:func:`frame_pixels` of the frame, made once."""
        if not self._pixels:
            self._pixels.append(frame_pixels(self.camera, self.gbuffer, self.material))
        return self._pixels[0]

    def probes(self):
        if not self._probes:
            self._probes.append(frame_pairs(self.camera, self.gbuffer, self.count, self.material,
                                            pixels=self.pixels()))
        return self._probes[0]

    def shaded_count(self) -> int:
        """The frame's shaded pixels (a non-zero, finite normal; coverage above 0)."""
        if self._shaded is None:
            N = np.asarray(self.gbuffer.normal)
            with np.errstate(invalid="ignore"):
                ok = across(np.logical_or, N.reshape(-1, 3) != 0) & across(
                    np.logical_and, np.isfinite(N.reshape(-1, 3)))
            cov = getattr(self.gbuffer, "coverage", None)
            if cov is not None:
                ok &= np.asarray(cov).reshape(-1) > 0
            self._shaded = int(ok.sum())
        return self._shaded

    def horizon_misses(self, tables) -> int:
        """How many of the frame's shaded pixels ``tables`` cannot shade within their budget
        (:meth:`horizon_miss_pixels`)."""
        return len(self.horizon_miss_pixels(tables))

    def horizon_miss_pixels(self, tables) -> np.ndarray:
        """The flat indices of the frame's shaded pixels ``tables`` cannot shade within their budget
        (:func:`clphong.model.env_table.horizon_misses`), from n·v formed in float32 as
        N·(eye − P)/(|N|·|eye − P|) (the kernels' v; v = n where P is the eye) and the
        pixels' term weights, HORIZON_CHUNK pixels at a time (small temporaries, reused).
        Pixels with a NaN or Inf input are the non-finite policy's."""
        g = self.gbuffer
        N = np.asarray(g.normal, np.float32).reshape(-1, 3)
        P = np.asarray(g.position, np.float32).reshape(-1, 3)
        cov = getattr(g, "coverage", None)
        cov = None if cov is None else np.asarray(cov).reshape(-1)
        view = view_vector(self.camera)
        eye = np.asarray(self.camera.position if view is None else view / np.linalg.norm(view),
                         np.float32)
        misses = []
        for a in range(0, len(N), HORIZON_CHUNK):
            part = slice(a, min(a + HORIZON_CHUNK, len(N)))
            n = N[part]
            with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
                nn = np.einsum("ij,ij->i", n, n)
                if view is not None:
                    c = n @ eye
                    c /= np.sqrt(nn)
                else:
                    D = eye - P[part]
                    dd = np.einsum("ij,ij->i", D, D)
                    c = np.einsum("ij,ij->i", n, D)
                    c /= np.sqrt(nn * dd)
                    c[dd == 0] = 1.0
                ok = (nn > 0) & np.isfinite(nn) & np.isfinite(c)
                if cov is not None:
                    ok &= cov[part] > 0
                d, sp = _probe_weights(g, part, self.material, np.float32)
                ok &= across(np.logical_and, np.isfinite(d)) & across(np.logical_and,
                                                                     np.isfinite(sp))
            where = np.arange(a, a + len(n))
            if not ok.all():
                c, n, d, sp, where = c[ok], n[ok], d[ok], sp[ok], where[ok]
            misses.append(where[_env_table.horizon_misses(tables, self.material, c, d, sp, n)])
        return np.concatenate(misses) if misses else np.zeros(0, np.intp)


#: Pixels of one step of :meth:`FrameSource.horizon_misses`.
HORIZON_CHUNK = 1 << 16


#: Part of FrameSource's digest: a change to how probes are chosen converts again.
FRAME_PROBES_VERSION = 1


def _convert(light: Light, where: str, material, view, max_error: float,
             nonfinite: str = "error", shade=None, pairs=None) -> EnvironmentLights:
    name = light.file
    policy = "background" if nonfinite == "background" else "error"   # what reading does
    shader = "numpy" if shade is None else shade.key
    if pairs is not None:       # a frame's probes: the key names them, not the view
        view, shader = None, f"{shader}; frame probes {pairs.digest()[:32]}"
    try:
        st = os.stat(name)
        key = (os.path.realpath(name), st.st_ino, st.st_size, st.st_mtime_ns, light.rotation,
               light.intensity, material, None if view is None else tuple(view), max_error, policy,
               shader)
    except OSError:
        key = None                        # read_envmap says what is wrong
    disk: list = []

    def find():
        digest = _file_digest(name) if key is not None else None
        disk.append(None if digest is None else _disk_key(digest, light, material, view,
                                                          max_error, policy, shader))
        found = None if disk[0] is None else _DISK.get(disk[0])
        return None if found is None else _load(found)

    def make():
        nonlocal view
        L, notes = _read_noting(name, where, nonfinite)
        probes = pairs.probes() if isinstance(pairs, FrameSource) else pairs
        if isinstance(pairs, FrameSource) and probes is None:
            view = view_vector(pairs.camera)     # no pixel to probe: every normal and view
        result = environment_lights(L, material, rotation=light.rotation,
                                    intensity=light.intensity, view=view, max_error=max_error,
                                    progress=_Progress(f"{where}: {name}"), shade=shade,
                                    pairs=probes)
        if disk[0] is not None:
            _save(disk[0], result, notes)
        return result, notes

    return _cached(_CACHE, key, find, make)


def directional_lights(env: EnvironmentLights, group: str | None = None) -> tuple[Light, ...]:
    """``env``'s lights as ``directional`` :class:`~clphong.model.scene.Light` objects
    (``direction = -l``, ``color`` the radiance, ``intensity`` 1) in ``group``."""
    return _scene.directional_lights(env.l, env.radiance, group)


def check_environment_maps(scene: Scene, *, nonfinite: str = "error",
                           max_error: float | None = None) -> None:
    """Read each environment map of ``scene`` as :func:`resolve_environment` would, and
    raise its one-line error (a SceneError naming the key) for the first that cannot be
    used, without converting: a batch whose frames resolve their own fails once, first.
    With ``max_error``, a map whose very content became tables under these settings before
    (the disk cache holds them) is not read again."""
    for i, lt in enumerate(scene.lights):
        if lt.type == "environment":
            if max_error is not None and _tabled_before(lt, scene.material, max_error, nonfinite):
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)   # the frames say them
                read_envmap(lt.file, environment_key(scene, i), nonfinite)


def resolve_environment(scene: Scene, *, max_error: float = DEFAULT_ENV_ERROR,
                        nonfinite: str = "error", shade=None, pairs=None,
                        tables: bool = False) -> ResolvedScene:
    """Replace every environment light of ``scene`` by directional lights.

    Parameters
    ----------
    scene : Scene
    max_error : float
        The relative error target (``--env-error``, default 1e-3) of
        :func:`clphong.model.environment.environment_lights`.
    nonfinite : {"error", "background", "pass"}
        NaN/Inf texels (``--nonfinite``, :func:`read_envmap`).
    shade : callable with a ``key``, optional
        The conversion's probe shader (``environment_lights(shade=...)``), e.g.
        :class:`clphong.device.envprobe.DeviceProbeShader`; None: float64 numpy. Its
        ``key`` is part of the cache keys.
    pairs : FrameSource or FrameProbes, optional
        The probes of one frame (:class:`FrameSource`, or :func:`frame_pairs`'s):
        each environment's estimate then speaks of that frame's pixels; their digest
        is part of the cache keys. None: every normal and view
        (:func:`clphong.model.environment.probe_pairs`).
    tables : bool
        Shade an environment from the kernels' tables where it can
        (:mod:`clphong.model.env_table`: Phong or no specular, no shininess map, a frame's
        pixels in ``pairs`` (a :class:`FrameSource`) whose lobes below their horizons the
        budget holds): its sun becomes directional lights and the tables go to
        ``scene.env_tables``. One environment at most; the lane kernel only.

    Returns
    -------
    ResolvedScene
        ``.scene`` is ``scene`` itself when it has no environment light.
        Conversions are cached per process (same file, unchanged on disk, same
        rotation, intensity, material, view and target) and on disk, in clphong's
        cache folder (``environment/``, keyed by the file's content, those settings
        and the converting code; at most DISK_KEEP entries): a second process
        converts nothing.

    Raises
    ------
    SceneError
        A map that cannot be used (:func:`read_envmap`), named by its scene key.
    """
    if not any(lt.type == "environment" for lt in scene.lights):
        return ResolvedScene(scene=scene)
    view = view_vector(scene.camera)
    lights: list[Light] = []
    done, tabled, paths, fallback = [], [], [], []
    for i, lt in enumerate(scene.lights):
        if lt.type != "environment":
            lights.append(lt)
            continue
        key = environment_key(scene, i)
        why = "tables not asked for (the obvious kernel, or the API's default)"
        if tables and tabled:
            why = "the kernels read one environment's tables: another has them"
        elif tables:
            why = _table_refusal(scene.material, pairs)
            if why is None:
                made = _tables(lt, key, scene.material, max_error, nonfinite)
                if isinstance(made, str):
                    why = made
                else:
                    miss = pairs.horizon_miss_pixels(made)
                    shaded = pairs.shaded_count()
                    if len(miss) > MIXED_SHARE * shaded:
                        why = (f"{len(miss):,} of {shaded:,} pixel(s) reflect so near their "
                               "horizon that the lobe the table counts below it may exceed the "
                               f"budget (more than {MIXED_SHARE:.0%})")
                    else:
                        suns = _scene.directional_lights(made.sun_l, made.sun_radiance, lt.group)
                        if not suns:           # its group keeps its layer
                            suns = (Light(type="directional", color=(0.0, 0.0, 0.0),
                                          direction=(0.0, -1.0, 0.0), group=lt.group),)
                        lights.extend(suns)
                        tabled.append((made, lt.group_name))
                        done.append(("tables", (i, made)))
                        if not len(miss):
                            paths.append((i, "tables", made.describe() + ": every pixel's lobe "
                                          "below its horizon is within the budget"))
                            continue
                        # the pixels the bound does not hold: this environment as lights,
                        # estimated on those pixels alone, in a second launch on them
                        sub = FrameSource(pairs.camera, pairs.gbuffer.pixels(miss), pairs.material)
                        r = _convert(lt, key, scene.material, view, max_error, nonfinite, shade, sub)
                        fallback.append((len(lights) - len(suns), len(suns), r, lt.group, miss))
                        done.append(("lights", (i, r)))
                        paths.append((i, "tables", made.describe() + f"; {len(miss):,} of "
                                      f"{shaded:,} pixel(s) reflect so near their horizon that "
                                      f"the lobe below it may exceed the budget: {r.count:,} "
                                      "directional lights there"))
                        continue
        r = _convert(lt, key, scene.material, view, max_error, nonfinite, shade, pairs)
        done.append(("lights", (i, r)))
        paths.append((i, "lights", why))
        if not r.met:
            warnings.warn(SceneWarning(
                f"{key}: {lt.file}: {r.count} lights (the most allowed) "
                f"reach an estimated {r.estimated_error:.2g} relative error, not the "
                f"{max_error:g} asked for (--env-error)"))
        lights.extend(directional_lights(r, lt.group))
    resolved = dataclasses.replace(scene, lights=tuple(lights), env_tables=tuple(tabled))
    other = None
    if fallback:                         # the tabled environment's suns become its lights
        at, n, r, group, miss = fallback[0]
        mine = tuple(directional_lights(r, group)) or (Light(
            type="directional", color=(0.0, 0.0, 0.0), direction=(0.0, -1.0, 0.0), group=group),)
        other = (dataclasses.replace(resolved, env_tables=(), lights=tuple(
            lights[:at]) + mine + tuple(lights[at + n:])), miss)
    return ResolvedScene(scene=resolved,
                         environments=tuple(x for k, x in done if k == "lights"),
                         tables=tuple(x for k, x in done if k == "tables"),
                         paths=tuple(paths), fallback=other)
