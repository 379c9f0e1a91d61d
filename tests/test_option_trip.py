"""Options are checked once (issue 26): ``clphong render``'s arguments are validated where
they come in, into RendererOptions and OutputOptions, and handed down finished.

Measured with tests/option_trip.py, which follows the arguments' values through the calls
of one render of the shipped samples. Before RendererOptions (the tree at a562dde) the
trip entered 21 rooms with 68 climbs back up and 296 calls, and ran, for one render,
``tonemap.operator`` 19 times, ``check_exposure`` 8, ``check_bits`` 8,
``check_compression`` 7, ``check_pixel_type`` 6, ``check_nonfinite`` 5 and
``path_options``, ``check_budget`` and ``check_env_error`` 4 times each.
"""

import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from option_trip import default_argv, trace

from clphong.model.options import RendererOptions
from clphong.pipeline.relighter import Relighter

#: Each validator's calls in one render: once, where the value comes in. The exceptions
#: are other doors, each checking for its own callers: argparse's converters (a usage
#: line, exit 2) for --env-error and --exr-compression, and the public writers of io/
#: and deliver/ (write_exr, write_scene_linear) and io.nonfinite.apply_nonfinite_policy,
#: which a library user calls directly.
ALLOWED = {
    "clphong.model.options.check_env_error": 2,        # argparse, RendererOptions
    "clphong.deliver.writers.check_compression": 3,        # argparse, OutputOptions, writer
    "clphong.io.atomic.check_pixel_type": 2,               # OutputOptions, write_exr
    "clphong.model.options.check_nonfinite": 2,            # RendererOptions, the frame's policy
}
VALIDATORS = ("clphong.model.options.check_budget", "clphong.model.options.check_nonfinite",
              "clphong.model.options.check_exposure", "clphong.model.options.check_fp64_directions",
              "clphong.model.options.path_options", "clphong.model.options.check_env_error",
              "clphong.deliver.writers.check_bits", "clphong.deliver.writers.check_compression",
              "clphong.io.atomic.check_pixel_type", "clphong.deliver.outputs.check_outputs",
              "clphong.device.display.DisplayTransform.__post_init__")


@pytest.fixture(scope="module")
def trip(tmp_path_factory):
    rc, trip = trace(default_argv(str(tmp_path_factory.mktemp("trip"))))
    assert rc == 0
    return trip


def test_every_option_is_checked_once(trip):
    calls = Counter(f"{m}.{f}" for m, f in trip.calls)
    for name in VALIDATORS:
        assert calls[name] <= ALLOWED.get(name, 1), (name, calls[name])
    # the checks that do run ran: a trip that saw no check would pass the line above
    assert calls["clphong.model.options.check_budget"] == 1
    assert calls["clphong.model.options.check_exposure"] == 1


def test_the_trip_is_no_longer_than_measured(trip):
    """13 rooms, 27 climbs back up and 28 returns (14 rooms at a562dde's successor, before
    check_env_error joined the registry in model.options); a change
    that sends the options back up to be checked again fails here."""
    assert len(trip.rooms) <= 13, trip.rooms
    assert len(trip.climbs) <= 27, trip.climbs
    assert trip.returns <= 28


@pytest.mark.parametrize("kwargs, cli", [
    (dict(max_error=-1.0), ["--max-error", "-1"]),
    (dict(nonfinite="nope"), None),
    (dict(path="fastest"), None),
])
def test_a_bad_value_reads_the_same_from_the_api_and_the_command(kwargs, cli, tmp_path):
    """RendererOptions is the one check: the API (Relighter), the options object and the
    command line give the same message."""
    with pytest.raises(Exception) as api:
        Relighter(str(Path(__file__).parent.parent / "gbuffers" / "spheres.toml"), **kwargs)
    with pytest.raises(Exception) as obj:
        RendererOptions(**kwargs)
    assert str(api.value) == str(obj.value)
    if cli is not None:
        argv = default_argv(str(tmp_path))[:5] + cli
        out = subprocess.run([sys.executable, "-m", "clphong", *argv], capture_output=True, text=True)
        assert out.returncode != 0 and str(obj.value) in out.stderr, out.stderr


def test_options_come_one_way_not_both():
    """options= and the same options as keyword arguments together are refused in one
    line (the keyword arguments would be dropped without a word)."""
    from clphong.device.renderer import Renderer

    scene = str(Path(__file__).parent.parent / "gbuffers" / "spheres.toml")
    with pytest.raises(ValueError, match="not both"):
        Relighter(scene, options=RendererOptions(path="fast"), max_error=1e-3)
    from clphong.model.scene import load_scene

    with pytest.raises(ValueError, match="not both"):
        Renderer(load_scene(scene), options=RendererOptions(), nonfinite="error")
    r = Relighter(scene, options=RendererOptions(path="fast", max_error=1e-3))
    assert r.renderer.max_error == pytest.approx(1e-3) and r.spec.path == "fast"
    assert r.spec.build().options == r.options


def test_layers_given_as_one_string_are_split_as_the_command_line_does():
    """``aovs="diffuse,specular"`` (the --aov form) stays two layers, not letters."""
    assert RendererOptions(aovs="diffuse, specular").aovs == ("diffuse", "specular")
    r = Relighter(str(Path(__file__).parent.parent / "gbuffers" / "spheres.toml"),
                  aovs="diffuse,specular")
    assert r.renderer.aovs == ("diffuse", "specular") and r.spec.aovs == ("diffuse", "specular")


def test_a_spec_keeps_its_options_as_checked():
    """RelighterSpec normalises as RendererOptions does (env_error "0.01" -> 0.01), and
    RelighterSpec.of refuses a renderer option given twice or a name that is no field."""
    from clphong.model.options import finished
    from clphong.pipeline.relighter import RelighterSpec

    spec = RelighterSpec(scene="s.toml", env_error="0.01", aovs="diffuse")
    assert spec.env_error == 0.01 and spec.options.env_error == 0.01 and spec.aovs == ("diffuse",)
    with pytest.raises(TypeError, match="max_error"):
        RelighterSpec.of(RendererOptions(), scene="s.toml", max_error=1e-3)
    with pytest.raises(TypeError, match="lane"):
        RelighterSpec.of(RendererOptions(), scene="s.toml", lane=16)
    with pytest.raises(TypeError, match="missing"):
        finished(RendererOptions, path="fast")
