"""G-buffer channels: the buffers a G-buffer has, the layouts of the renderers that write
them (layer and pass names, component letters), the user's channel mapping, and the
detection of a layout from a file's channel names."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from ..core.errors import GBufferError
from ..model.scene import MAP_KEYS, MATERIAL_MAPS

__all__ = ["parse_channel_mapping", "CHANNEL_KEYS", "VECTOR_KEYS", "SCALAR_KEYS", "REQUIRED",
           "OPTIONAL", "WRITE_CONVENTIONS", "BAND_ROWS"]

#: The three buffers every G-buffer needs.
REQUIRED = ("position", "normal", "albedo")
#: Keys of ``channels=`` that name 3-channel buffers.
VECTOR_KEYS = REQUIRED + tuple(k for k, c in MATERIAL_MAPS.items() if c == 3)
#: Keys of ``channels=`` that name 1-channel buffers.
SCALAR_KEYS = ("coverage",) + tuple(k for k, c in MATERIAL_MAPS.items() if c == 1)
#: Optional buffers: coverage and the material maps (clphong.model.scene.MAP_KEYS).
OPTIONAL = ("coverage", *MAP_KEYS)
#: Every valid key of ``channels=``, in a stable order.
CHANNEL_KEYS = REQUIRED + OPTIONAL
#: Rows per band of a G-buffer read (:meth:`_ExrFile.read_stacked`), rounded to whole
#: chunks of the file: 64 rows of 1920 pixels and 10 float channels are 4.9 MB.
BAND_ROWS = 64
#: Conventions :func:`write_gbuffer` can write.
WRITE_CONVENTIONS = ("generic", "blender", "blender-new", "arnold", "mitsuba")

_COMPONENTS = (("X", "Y", "Z"), ("x", "y", "z"), ("R", "G", "B"), ("r", "g", "b"))

_LOOKED_FOR = {
    "position": "P.X/Y/Z (or .x/y/z, .R/G/B), pos.*, <ViewLayer>.Position.*",
    "normal": "N.*, sh_normal.*, geo_normal.*, <ViewLayer>.Normal.*",
    "albedo": "albedo.*, diffuse_albedo.*, <ViewLayer>.DiffCol.*, <ViewLayer>.Diffuse Color.*",
}

# Layer names of each required buffer per convention (single-file detection).
_GENERIC_LAYERS = {"position": ("P",), "normal": ("N",), "albedo": ("albedo", "diffuse_albedo")}
_MITSUBA_LAYERS = {"position": ("pos",), "normal": ("sh_normal", "geo_normal"), "albedo": ("albedo",)}
_BLENDER_PASSES = {"position": ("Position",), "normal": ("Normal",), "albedo": ("DiffCol", "Diffuse Color")}


# --------------------------------------------------------------------------- channel mapping


def _show(name: str) -> str:
    """A channel name for a message: escaped when it has control or undecodable
    characters (a newline, found by fuzzing), so that the message stays one line."""
    return name if name.isprintable() else repr(name)


def _short(names: Sequence[str], limit: int = 16) -> str:
    names = [_show(n) for n in names]
    if not names:
        return "(no channels)"
    if len(names) <= limit:
        return ", ".join(names)
    return ", ".join(names[:limit]) + f", ... (+{len(names) - limit} more)"


def _normalise_mapping(channels) -> dict[str, tuple[str, object]]:
    """Validate ``channels=``; return key -> ("prefix"|"name"|"list", value)."""
    if channels is None:
        return {}
    if not isinstance(channels, Mapping):
        raise GBufferError(f"channels must be a mapping of key to channel names, "
                           f"got {type(channels).__name__}")
    out: dict[str, tuple[str, object]] = {}
    for key, value in channels.items():
        if key not in CHANNEL_KEYS:
            raise GBufferError(f"unknown channel mapping key {key!r}; valid keys: {', '.join(CHANNEL_KEYS)}")
        want = 3 if key in VECTOR_KEYS else 1
        if isinstance(value, str):
            parts = [p.strip() for p in value.split(",")] if "," in value else None
            if parts is None:
                if not value.strip():
                    raise GBufferError(f"channel mapping {key}= is empty; give a layer prefix or "
                                       f"{want} channel name(s)")
                out[key] = ("prefix" if want == 3 else "name", value.strip())
                continue
        elif isinstance(value, Sequence):
            parts = [str(p).strip() for p in value]
        else:
            raise GBufferError(f"channel mapping {key}: expected a string or a list of channel "
                               f"names, got {type(value).__name__}")
        if any(not p for p in parts):
            raise GBufferError(f"channel mapping {key}={','.join(map(_show, parts))} has an empty channel name")
        if len(parts) != want:
            raise GBufferError(f"channel mapping {key}={','.join(map(_show, parts))}: {key} needs {want} "
                               f"channel name{'s' if want > 1 else ''}, got {len(parts)}")
        out[key] = ("list", parts)
    return out


def parse_channel_mapping(items: Sequence[str]) -> dict[str, str | list[str]]:
    """Parse the command-line form ``--channels KEY=VALUE`` (repeatable).

    Parameters
    ----------
    items : sequence of str
        Items like ``"position=P.X,P.Y,P.Z"`` or ``"normal=Nw"``.

    Returns
    -------
    dict
        Key -> layer prefix (str) or list of channel names, suitable for
        ``read_gbuffer(..., channels=...)``.

    Raises
    ------
    GBufferError
        Naming the bad item: no ``=``, an unknown key, an empty value, a
        wrong number of channel names, or a key given twice.

    Examples
    --------
    >>> parse_channel_mapping(["position=P.X,P.Y,P.Z", "normal=Nw"])
    {'position': ['P.X', 'P.Y', 'P.Z'], 'normal': 'Nw'}
    """
    if isinstance(items, str):
        items = [items]
    result: dict[str, str | list[str]] = {}
    for item in items:
        if "=" not in item:
            raise GBufferError(f"--channels {item!r}: expected KEY=CHANNELS, e.g. position=P.X,P.Y,P.Z")
        key, value = (s.strip() for s in item.split("=", 1))
        if key not in CHANNEL_KEYS:
            raise GBufferError(f"--channels {item!r}: unknown key {key!r}; valid keys: {', '.join(CHANNEL_KEYS)}")
        if key in result:
            raise GBufferError(f"--channels {item!r}: {key} is given more than once")
        if not value:
            raise GBufferError(f"--channels {item!r}: no channels after '='")
        parsed: str | list[str] = [p.strip() for p in value.split(",")] if "," in value else value
        try:
            _normalise_mapping({key: parsed})
        except GBufferError as exc:
            raise GBufferError(f"--channels {item!r}: {exc}") from None
        result[key] = parsed
    return result


# --------------------------------------------------------------------------- channel lookup


class _Channels:
    """Channel names of one file, with name lookup helpers."""

    def __init__(self, names: Sequence[str]):
        self.names = list(names)
        self.set = set(self.names)
        self.layers: dict[str, list[str]] = {}
        for n in self.names:
            if "." in n:
                self.layers.setdefault(n.rsplit(".", 1)[0], []).append(n)

    def vector(self, layer: str) -> list[str] | None:
        """Channels of vector layer ``layer`` ("" = plain R,G,B / X,Y,Z)."""
        for comps in _COMPONENTS:
            chans = [f"{layer}.{c}" if layer else c for c in comps]
            if all(c in self.set for c in chans):
                return chans
        return None

    def scalar(self, name: str, path: str, key: str) -> list[str] | None:
        """The channel ``name`` or the only channel of layer ``name``."""
        if name in self.set:
            return [name]
        chans = self.layers.get(name)
        if not chans:
            return None
        if len(chans) == 1:
            return chans
        raise GBufferError(f"{path}: layer {name!r} has {len(chans)} channels ({_short(chans, 6)}) "
                           f"but {key} needs one; choose it with --channels {key}={chans[0]}")

    def blender_prefixes(self) -> list[str]:
        """View-layer prefixes ("ViewLayer." or "") of Blender passes, in channel order."""
        prefixes: list[str] = []
        passes = tuple(p for names in _BLENDER_PASSES.values() for p in names)
        for layer in self.layers:
            for p in passes:
                if layer == p or layer.endswith("." + p):
                    prefix = layer[: len(layer) - len(p)]
                    if prefix not in prefixes:
                        prefixes.append(prefix)
        return prefixes


@dataclass
class _Layout:
    """How one file names its buffers: convention, Blender prefix, found channels."""

    convention: str
    prefix: str = ""                                   # Blender view layer + "." (or "")
    found: dict[str, list[str]] = field(default_factory=dict)
    albedo_layer: str | None = None

    @property
    def view_layer(self) -> str | None:
        return self.prefix[:-1] if self.prefix else None


def _layer_of(chans: list[str]) -> str | None:
    return chans[0].rsplit(".", 1)[0] if "." in chans[0] else None


def _is_rgb(chans: list[str] | None) -> bool:
    return bool(chans) and chans[0].rsplit(".", 1)[-1] in ("R", "r")


def _candidate_layouts(ch: _Channels, attributes: Mapping[str, object]) -> list[_Layout]:
    """Every convention's view of a multichannel file, in detection order."""
    def first_present(candidates: Mapping[str, Sequence[str]]) -> dict:
        """For each buffer, the channels of the first candidate layer present."""
        found = {}
        for key, layers in candidates.items():
            for layer in layers:
                chans = ch.vector(layer)
                if chans:
                    found[key] = chans
                    break
        return found

    layouts = []
    # generic / arnold
    found = first_present(_GENERIC_LAYERS)
    arnold = (found.get("albedo", [""])[0].startswith("diffuse_albedo.")
              or _is_rgb(found.get("position")) or _is_rgb(found.get("normal"))
              or any(str(k).startswith("arnold/") for k in attributes))
    layouts.append(_Layout("arnold" if arnold else "generic", "", found,
                           _layer_of(found["albedo"]) if "albedo" in found else None))
    # mitsuba
    found = first_present(_MITSUBA_LAYERS)
    layouts.append(_Layout("mitsuba", "", found, "albedo" if "albedo" in found else None))
    # blender, one layout per view layer
    for prefix in ch.blender_prefixes():
        found = {}
        for key, passes in _BLENDER_PASSES.items():
            for p in passes:
                chans = ch.vector(prefix + p)
                if chans:
                    found[key] = chans
                    break
        layouts.append(_Layout("blender", prefix, found,
                               _layer_of(found["albedo"]) if "albedo" in found else None))
    return layouts


def _detect_single(ch: _Channels, key: str, attributes: Mapping[str, object]) -> _Layout | None:
    """Find one required buffer in a file given for that buffer alone."""
    for layout in _candidate_layouts(ch, attributes):
        if key in layout.found:
            return _Layout(layout.convention, layout.prefix, {key: layout.found[key]},
                           layout.albedo_layer if key == "albedo" else None)
    chans = ch.vector("")
    if chans:
        return _Layout("rgb-files", "", {key: chans}, None)
    return None


def _find_optional(ch: _Channels, key: str, layout: _Layout, path: str) -> list[str] | None:
    """Detect coverage or a material map in a file described by ``layout``."""
    prefixes = [layout.prefix, ""] if layout.prefix else [""]
    if key == "coverage":
        if layout.convention == "blender":
            for pre in prefixes:
                for name in (pre + "Combined.A", pre + "Alpha"):
                    chans = ch.scalar(name, path, key)
                    if chans:
                        return chans
        for name in ("A", "RGBA.A", "rgba.A"):          # rgba.A: Nuke's multi-part beauty
            if name in ch.set:
                return [name]
        if layout.albedo_layer and f"{layout.albedo_layer}.A" in ch.set:
            return [f"{layout.albedo_layer}.A"]
        return None
    if key == "specular_color":
        for pre in prefixes:
            for layer in ("specular_color", "Cs"):
                chans = ch.vector(pre + layer)
                if chans:
                    return chans
        return None
    name = "shininess" if key == "h" else key
    for pre in prefixes:
        chans = ch.scalar(pre + name, path, key)
        if chans:
            return chans
    return None


def _explicit(ch: _Channels, key: str, spec: tuple[str, object], path: str,
              required: bool = True) -> list[str] | None:
    """Resolve an explicit ``channels=`` entry in one file (None if absent and not required)."""
    kind, value = spec
    if kind == "list":
        missing = [c for c in value if c not in ch.set]
        if not missing:
            return list(value)
        if not required:
            return None
        raise GBufferError(f"{path}: channel {missing[0]!r} ({key}, from channels "
                           f"{key}={','.join(map(_show, value))}) not found; the file has: {_short(ch.names)}")
    if kind == "prefix":
        chans = ch.vector(value)
        if chans or not required:
            return chans
        raise GBufferError(f"{path}: no layer {value!r} with .X/.Y/.Z, .x/.y/.z or .R/.G/.B "
                           f"channels ({key}, from channels {key}={value}); the file has: {_short(ch.names)}")
    chans = ch.scalar(value, path, key)
    if chans or not required:
        return chans
    raise GBufferError(f"{path}: channel {value!r} ({key}, from channels {key}={value}) not found; "
                       f"the file has: {_short(ch.names)}")
