"""Lights files (``lights = "rig.csv"`` / ``"rig.npz"``): the same lights, checks and
messages as ``[[light]]`` tables, naming the file, the row and the column."""

from __future__ import annotations

import os
import re
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, find, given, settings
from hypothesis import strategies as st

from clphong.core.errors import SceneError
from clphong.core.floats import FLT_MAX
from clphong.model.light_table import (
    COLUMNS,
    column_of,
    light_columns,
    read_light_table,
    write_light_table,
)
from clphong.model.scene import SceneWarning, load_scene, parse_scene

MATERIAL = {"model": "phong", "k_a": 0.1, "k_d": 0.7, "k_s": 0.2, "h": 32.0}
SCENE_HEAD = ('[material]\nmodel = "phong"\nk_a = 0.1\nk_d = 0.7\nk_s = 0.2\nh = 32.0\n')


def quiet(fn, *args):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return fn(*args)


def scene_with(tmp_path, body: str, name: str = "rig.csv", tables: str = "", folder: str = ""):
    """scene.toml with ``lights = name`` (and ``tables``), the lights file holding ``body``."""
    d = tmp_path / folder if folder else tmp_path
    d.mkdir(exist_ok=True)
    (d / name).write_text(body) if isinstance(body, str) else (d / name).write_bytes(body)
    scene = tmp_path / "scene.toml"
    scene.write_text(f'lights = "{folder + "/" if folder else ""}{name}"\n' + SCENE_HEAD + tables)
    return scene


def error_of(scene) -> str:
    with pytest.raises(SceneError) as info:
        quiet(load_scene, scene)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


# A rig written by hand both ways: [[light]] tables, and the same rows as CSV.
TABLES = """
[[light]]
type = "point"
position = [1.0, 2.0, 3.0]
color = [1.0, 0.5, 0.25]
intensity = 5.0
attenuation = [1.0, 0.1, 0.05]
group = "key"

[[light]]
type = "point"
position = [-1, 0.5, 2]
power = 100

[[light]]
type = "spot"
position = [0.0, 4.0, 0.0]
direction = [0.0, -2.0, -0.5]
inner_angle = 10.0
outer_angle = 30.0
intensity = 30.0
attenuation = [0.0, 0.0, 1.0]
group = "key"

[[light]]
type = "directional"
direction = [-1.0, -1.5, -1.0]
intensity = 3.0
color = [0.9, 0.9, 1.0]

[[light]]
type = "ambient"
intensity = 0.5
color = [0.2, 0.2, 0.2]
group = "fill"
"""
CSV = """\
# the same five lights as TABLES
type,x,y,z,dx,dy,dz,r,g,b,intensity,power,c0,c1,c2,inner_angle,outer_angle,group
point,1.0,2.0,3.0,,,,1.0,0.5,0.25,5.0,,1.0,0.1,0.05,,,key
point,-1,0.5,2,,,,1,1,1,,100,,,,,,
spot, 0.0, 4.0, 0.0, 0.0, -2.0, -0.5, 1, 1, 1, 30.0, , 0.0, 0.0, 1.0, 10.0, 30.0, key

directional,,,,-1.0,-1.5,-1.0,0.9,0.9,1.0,3.0,,,,,,,
ambient,,,,,,,0.2,0.2,0.2,0.5,,,,,,,fill
"""


def test_csv_rows_are_the_same_lights_as_tables(tmp_path):
    by_tables = tmp_path / "t.toml"
    by_tables.write_text(SCENE_HEAD + TABLES)
    a = quiet(load_scene, by_tables)
    b = quiet(load_scene, scene_with(tmp_path, CSV))
    assert len(b.lights) == 5 and b.lights == a.lights
    assert b.light_groups == a.light_groups == ("key", "default", "fill")
    for k in a.light_arrays:
        assert np.array_equal(a.light_arrays[k], b.light_arrays[k]), k
    assert b.lights[1].power == 100.0 and b.lights[1].attenuation == (0.0, 0.0, 1.0)


@pytest.mark.parametrize("ext", ["csv", "npz"])
def test_written_rig_round_trips_with_tables_first(tmp_path, ext):
    """Lights written as a lights file (light_columns / write_light_table) read back
    as the same lights and light arrays as the [[light]] tables; a scene's own tables
    come first, then the file's rows."""
    rng = np.random.default_rng(5)
    base = quiet(load_scene, _write(tmp_path / "t.toml", SCENE_HEAD + TABLES))
    rig = []
    for k in range(300):
        lt = base.lights[k % 4]
        rig.append(lt.__class__(**{**lt.__dict__, "color": tuple(rng.uniform(0, 1, 3).tolist()),
                                   **({"position": tuple(rng.uniform(-5, 5, 3).tolist())}
                                      if lt.position is not None else {})}))
    first = base.lights[4]
    data = {"material": MATERIAL, "light": [first.to_dict()] + [lt.to_dict() for lt in rig]}
    ref = quiet(parse_scene, data)
    write_light_table(tmp_path / f"rig.{ext}", rig)
    got = quiet(parse_scene, {"material": MATERIAL, "light": [first.to_dict()],
                              "lights": str(tmp_path / f"rig.{ext}")})
    assert got.lights == ref.lights
    assert set(got.light_arrays) == set(ref.light_arrays)
    for k in ref.light_arrays:
        assert np.array_equal(got.light_arrays[k], ref.light_arrays[k]), k


def _write(path, text):
    path.write_text(text)
    return path


def test_bench_rig_as_npz_equals_its_toml(tmp_path):
    """The bench's wide scene (point lights with attenuation (1, 0.1, 0.05)), its lights
    from an .npz made here with numpy.savez, against the same scene as TOML tables."""
    from clphong.tools.bench import bench_scene

    sc = bench_scene("wide", 512)
    pts = [lt for lt in sc.lights if lt.type == "point"]
    np.savez(tmp_path / "rig.npz",
             x=np.array([lt.position[0] for lt in pts]), y=np.array([lt.position[1] for lt in pts]),
             z=np.array([lt.position[2] for lt in pts]),
             r=np.array([lt.color[0] for lt in pts], np.float64),
             g=np.array([lt.color[1] for lt in pts]), b=np.array([lt.color[2] for lt in pts]),
             intensity=np.full(len(pts), pts[0].intensity), c0=np.ones(len(pts)),
             c1=np.full(len(pts), 0.1), c2=np.full(len(pts), 0.05))
    data = sc.to_dict()
    ref = quiet(parse_scene, data)
    data["light"] = [lt for lt in data["light"] if lt["type"] != "point"]
    data["lights"] = str(tmp_path / "rig.npz")
    got = quiet(parse_scene, data)
    assert got.lights == ref.lights
    for k in ref.light_arrays:
        assert np.array_equal(got.light_arrays[k], ref.light_arrays[k]), k


def test_path_is_relative_to_the_scene_folder(tmp_path):
    scene = scene_with(tmp_path, "x,y,z\n1,2,3\n", folder="rigs")
    assert quiet(load_scene, scene).lights[0].position == (1.0, 2.0, 3.0)
    (tmp_path / "rigs" / "rig.csv").unlink()
    msg = error_of(scene)
    assert msg == (f"{scene}: lights: cannot read lights file {tmp_path / 'rigs' / 'rig.csv'}: "
                   "no such file")


def test_defaults_without_columns(tmp_path):
    """No type column: point lights; no color: white; no intensity: 1; no c0..c2: no falloff;
    spots without angle columns: glTF's 0 and 45 degrees."""
    lts = quiet(load_scene, scene_with(tmp_path, "x,y,z\n1,2,3\n")).lights
    assert (lts[0].type, lts[0].color, lts[0].intensity, lts[0].attenuation, lts[0].group) == \
        ("point", (1.0, 1.0, 1.0), 1.0, (1.0, 0.0, 0.0), None)
    spot = quiet(load_scene, scene_with(tmp_path, "type,x,y,z,dx,dy,dz\nspot,0,1,0,0,-3,0\n")).lights[0]
    assert (spot.inner_angle, spot.outer_angle, spot.direction) == (0.0, 45.0, (0.0, -1.0, 0.0))


def test_empty_rig_and_comments(tmp_path):
    assert quiet(load_scene, scene_with(tmp_path, "# nothing yet\ntype,x,y,z\n\n")).lights == ()


def csv_case(header: str, *rows: str) -> str:
    return "\n".join((header,) + rows) + "\n"


# (id, CSV text, the whole message after "rig.csv: ")
CSV_ERRORS = [
    ("negative-intensity", csv_case("x,y,z,intensity", "1,2,3,1", "1,2,3,-1"),
     "row 1 (line 3): intensity: must be >= 0, got -1.0"),
    ("negative-color", csv_case("x,y,z,r,g,b", "1,2,3,1,-0.5,1"),
     "row 0 (line 2): g: must be >= 0, got -0.5"),
    ("nan-and-inf-counted", csv_case("x,y,z,intensity,c0,c1,c2", "1,2,3,1,1,0,0", "1,2,3,nan,1,0,0",
                                     "1,2,3,1,1,-inf,0", "1,2,3,NaN,1,0,0"),
     "row 1 (line 3): intensity: must be finite, got nan; 3 non-finite cell(s) in all "
     "(intensity 2, c1 1); NaN and Inf are refused"),
    ("not-a-number", csv_case("x,y,z", "1,2,3", "1,two,3"),
     "row 1 (line 3): y: expected a number, got 'two'"),
    ("unknown-column", csv_case("x,y,z,intesity", "1,2,3,1"),
     "line 1: column 'intesity': unknown column; did you mean 'intensity'?"),
    ("vector-column", csv_case("position,intensity", "1,1"),
     "line 1: column 'position': unknown column; a position is the three columns x, y, z"),
    ("duplicate-column", csv_case("x,y,z,x", "1,2,3,4"),
     "line 1: column 'x' is there twice (cells 1 and 4)"),
    ("ragged-row", csv_case("x,y,z", "1,2,3", "1,2"),
     "row 1 (line 3): expected 3 cells, as in the header (line 1), got 2"),
    ("part-of-a-vector", csv_case("x,y,intensity", "1,2,1"),
     "column z: missing; the position is the three columns x, y, z (the file has x, y)"),
    ("bad-type", csv_case("type,x,y,z", "point,1,2,3", "pont,1,2,3"),
     "row 1 (line 3): type: invalid value 'pont'; expected one of 'point', 'spot', "
     "'directional', 'ambient'; did you mean 'point'?"),
    ("environment-row", csv_case("type,x,y,z", "environment,,,"),
     "row 0 (line 2): type: an 'environment' light needs a map file: give it as a [[light]] "
     "table in the scene"),
    ("empty-type", csv_case("type,x,y,z", ",1,2,3"),
     "row 0 (line 2): type: empty; one of 'point', 'spot', 'directional', 'ambient'"),
    ("cell-the-type-does-not-take", csv_case("type,x,y,z,dx,dy,dz", "point,1,2,3,0,0,1"),
     "row 0 (line 2): dx: 0 but a 'point' light takes no direction (only 'spot' and "
     "'directional' lights do); leave the cell empty"),
    ("empty-needed-cell", csv_case("type,x,y,z,dx,dy,dz", "directional,,,,0,0,1", "point,1,,3,,,"),
     "row 1 (line 3): y: empty; a 'point' light takes position and the file has the column "
     "(1 such cell(s) in column y)"),
    ("intensity-and-power", csv_case("x,y,z,intensity,power", "1,2,3,1,100"),
     "row 0 (line 2): power: give power (watts, with Cycles' 1/d^2 falloff) or intensity, not both"),
    ("neither-intensity-nor-power", csv_case("x,y,z,intensity,power", "1,2,3,,"),
     "row 0 (line 2): intensity: empty; a 'point' light gives intensity or power "
     "(1 such cell(s) in column intensity)"),
    ("power-and-attenuation", csv_case("x,y,z,power,c0,c1,c2", "1,2,3,100,1,0,0"),
     "row 0 (line 2): power: give power (watts, with Cycles' 1/d^2 falloff) or attenuation, "
     "not both"),
    ("no-position-columns", csv_case("type,intensity", "ambient,1", "point,2"),
     "row 1 (line 3): x, y, z: missing; a 'point' light needs a position: give the columns x, y, z"),
    ("attenuation", csv_case("x,y,z,c0,c1,c2", "1,2,3,1,0,0", "1,2,3,1,-1,0"),
     "row 1 (line 3): c0, c1, c2: p(d) = c0 + c1*d reaches 0 at d = 1 and goes negative for "
     "d > 1 (c1 = -1 < 0 with c2 = 0); need c1 >= 0; got [1.0, -1.0, 0.0]"),
    ("subnormal-coefficient", csv_case("x,y,z,c0,c1,c2", "1,2,3,1,1e-40,0"),
     "row 0 (line 2): c1: 1e-40 is nonzero but below the smallest normal float32, so the kernels "
     "(which flush subnormals) take it as 0; write 0, or at least 1.17549435e-38 in magnitude"),
    ("cone", csv_case("type,x,y,z,dx,dy,dz,inner_angle,outer_angle", "spot,0,0,0,0,0,-1,20,20"),
     "row 0 (line 2): inner_angle: 20.0 is not less than outer_angle = 20.0; the cone fades from "
     "inner to outer, so 0 <= inner < outer <= 90 (degrees)"),
    ("group", csv_case("x,y,z,group", "1,2,3,key", "1,2,3,diffuse"),
     "row 1 (line 3): group: 'diffuse' is the name of an AOV layer (diffuse, specular); "
     "choose another group name"),
    ("zero-direction", csv_case("type,dx,dy,dz", "directional,0,0,0"),
     "row 0 (line 2): dx, dy, dz: zero-length vector [0.0, 0.0, 0.0] has no direction"),
    ("radiance-beyond-float32", csv_case("x,y,z,intensity,r,g,b", "1,2,3,1e30,1e10,1,1"),
     "row 0 (line 2): intensity: color x intensity = 1e+40 is beyond the float32 range the "
     "kernels compute in (|x| <= 3.40282e+38)"),
    ("position-beyond-float32", csv_case("x,y,z", "1,2,4e38"),
     "row 0 (line 2): z: 4e+38 is beyond the float32 range the kernels compute in "
     "(|x| <= 3.40282e+38)"),
    ("no-header", "", "no header row; the first line names the columns, e.g. type,x,y,z,r,g,b,intensity"),
    ("long-text-cell", csv_case("x,y,z,group", "1,2,3," + "g" * 300),
     "row 0 (line 2): group: 300 characters; a type or group name is at most 63"),
]


@pytest.mark.parametrize("case, body, expected", CSV_ERRORS, ids=[c[0] for c in CSV_ERRORS])
def test_csv_error_names_file_row_and_column(tmp_path, case, body, expected):
    assert error_of(scene_with(tmp_path, body)) == f"rig.csv: {expected}".replace(
        "rig.csv", str(tmp_path / "rig.csv"), 1)


def test_first_bad_row_is_reported(tmp_path):
    """A value problem in row 1 comes before a structural one in row 2, and the other way."""
    body = csv_case("type,x,y,z,intensity", "point,1,2,3,1", "point,1,2,3,-1", "pont,1,2,3,1")
    assert ": row 1 (line 3): intensity: must be >= 0" in error_of(scene_with(tmp_path, body))
    body = csv_case("type,x,y,z,intensity", "point,1,2,3,1", "pont,1,2,3,1", "point,1,2,3,-1")
    assert ": row 1 (line 3): type: invalid value 'pont'" in error_of(scene_with(tmp_path, body))


def test_the_value_messages_are_the_light_tables(tmp_path):
    """For the same light, the problem after the column is the [[light]] table's own."""
    for light, row in [({"intensity": -2.0}, "1,2,3,-2,1,0,0"),
                       ({"attenuation": [1.0, -3.0, 1.0]}, "1,2,3,1,1,-3,1"),
                       ({"attenuation": [0.0, -1.0, 1.0]}, "1,2,3,1,0,-1,1"),
                       ({"intensity": 1e38, "attenuation": [1e-3, 0.0, 0.0]}, "1,2,3,1e38,1e-3,0,0")]:
        table = {"type": "point", "position": [1.0, 2.0, 3.0], "intensity": 1.0,
                 "attenuation": [1.0, 0.0, 0.0], **light}
        with pytest.raises(SceneError) as toml_error:
            quiet(parse_scene, {"material": MATERIAL, "light": [table]}, "s.toml")
        problem = re.sub(r" \(light\[0\] is the 1st \[\[light\]\]\)$", "",
                         str(toml_error.value).split(": ", 2)[2])
        msg = error_of(scene_with(tmp_path, csv_case("x,y,z,intensity,c0,c1,c2", row)))
        assert msg.endswith(f": {problem}"), (msg, problem)


def test_a_conservative_flag_is_cleared_by_the_exact_check(tmp_path):
    """A position just above FLT_MAX that rounds to it as float32 is legal in a table;
    the vectorised check flags it and the exact one clears it."""
    x = FLT_MAX * (1 + 2.0 ** -26)
    assert x > FLT_MAX
    table = {"type": "point", "position": [x, 0.0, 0.0]}
    ref = quiet(parse_scene, {"material": MATERIAL, "light": [table, table]})
    got = quiet(load_scene, scene_with(tmp_path, csv_case("x,y,z", f"{x!r},0,0", f"{x!r},0,0")))
    assert got.lights == ref.lights


# ------------------------------------------------------------------ .npz


def npz_bytes(tmp_path, **arrays) -> bytes:
    np.savez(tmp_path / "made.npz", **arrays)
    return (tmp_path / "made.npz").read_bytes()


NPZ_ERRORS = [
    ("infinite-counted", dict(x=np.array([1.0, np.inf]), y=np.zeros(2), z=np.array([-np.inf, 0.0])),
     "row 0: z: must be finite, got -inf; 2 infinite cell(s) in all (x 1, z 1); NaN and Inf are refused"),
    ("nan-where-needed", dict(x=np.array([1.0, np.nan]), y=np.zeros(2), z=np.zeros(2)),
     "row 1: x: NaN (an empty cell); a 'point' light takes position and the file has the column "
     "(1 such cell(s) in column x)"),
    ("negative", dict(x=np.zeros(3), y=np.zeros(3), z=np.zeros(3), intensity=np.array([1, 2, -3])),
     "row 2: intensity: must be >= 0, got -3.0"),
    ("two-dimensional", dict(position=np.zeros((2, 3))),
     "array 'position': unknown column; a position is the three columns x, y, z "
     "(np.savez(f, x=a[:, 0], y=a[:, 1], z=a[:, 2]))"),
    ("not-1d", dict(x=np.zeros((2, 1)), y=np.zeros(2), z=np.zeros(2)),
     "array x: expected a 1-D array, one value a row, got shape (2, 1) (a 2-D array: give one "
     "1-D array per column, e.g. x, y, z)"),
    ("lengths", dict(x=np.zeros(3), y=np.zeros(2), z=np.zeros(3)),
     "array y has 2 rows but x has 3; every column has one value a row"),
    ("bool", dict(x=np.zeros(1), y=np.zeros(1), z=np.zeros(1), intensity=np.array([True])),
     "array intensity: expected numbers (a float or integer array), got booleans (dtype bool)"),
    ("text-for-numbers", dict(x=np.array(["1"]), y=np.zeros(1), z=np.zeros(1)),
     "array x: expected numbers (a float or integer array), got text (dtype <U1)"),
    ("numbers-for-text", dict(x=np.zeros(1), y=np.zeros(1), z=np.zeros(1), type=np.zeros(1)),
     "array type: expected text (a str array), got dtype float64"),
    ("objects", dict(x=np.zeros(1), y=np.zeros(1), z=np.zeros(1),
                     group=np.array(["key"], dtype=object)),
     "array group: holds Python objects (dtype object), which are not read (allow_pickle=False); "
     "save numbers as a float array and text as a str array"),
    ("unknown", dict(x=np.zeros(1), y=np.zeros(1), z=np.zeros(1), colour=np.zeros(1)),
     "array 'colour': unknown column; did you mean 'color'?"),
]


@pytest.mark.parametrize("case, arrays, expected", NPZ_ERRORS, ids=[c[0] for c in NPZ_ERRORS])
def test_npz_error_names_file_row_and_column(tmp_path, case, arrays, expected):
    if case == "unknown":
        expected = expected.replace("did you mean 'color'?", "the columns are " + ", ".join(COLUMNS)) \
            if not __import__("difflib").get_close_matches("colour", COLUMNS, n=1) else expected
    msg = error_of(scene_with(tmp_path, npz_bytes(tmp_path, **arrays), "rig.npz"))
    assert msg == f"{tmp_path / 'rig.npz'}: {expected}"


def test_npz_nan_is_an_empty_cell_and_text_columns(tmp_path):
    """A mixed rig: NaN where a row's type takes no key; str arrays for type and group
    (bytes decoded as UTF-8), "" for no group; integers as numbers."""
    nan = np.nan
    arrays = dict(type=np.array([b"point", b"directional"]), x=np.array([1, nan]), y=np.array([2, nan]),
                  z=np.array([3, nan]), dx=np.array([nan, 0.0]), dy=np.array([nan, -1.0]),
                  dz=np.array([nan, 0.0]), intensity=np.array([2, 3], np.int32),
                  group=np.array(["key", ""]))
    lts = quiet(load_scene, scene_with(tmp_path, npz_bytes(tmp_path, **arrays), "rig.npz")).lights
    assert [(lt.type, lt.position, lt.direction, lt.intensity, lt.group) for lt in lts] == [
        ("point", (1.0, 2.0, 3.0), None, 2.0, "key"), ("directional", None, (0.0, -1.0, 0.0), 3.0, None)]


@pytest.mark.parametrize("body, fragment", [
    (b"not a zip at all", "rig.npz: this is not a zip file, not a .npz lights file"),
    (b"\x76\x2f\x31\x01rest", "rig.npz: this is an OpenEXR image, not a .npz lights file"),
])
def test_npz_that_is_not_a_zip(tmp_path, body, fragment):
    assert fragment in error_of(scene_with(tmp_path, body, "rig.npz"))


# ------------------------------------------------------------------ the file itself


def test_lights_key_and_file_kinds(tmp_path):
    assert "a lights file is .csv or .npz (by its name), not .txt" in \
        error_of(scene_with(tmp_path, "x,y,z\n", "rig.txt"))
    (tmp_path / "dir.csv").mkdir()
    scene = tmp_path / "d.toml"
    scene.write_text('lights = "dir.csv"\n' + SCENE_HEAD)
    assert error_of(scene) == (f"{tmp_path / 'dir.csv'}: cannot read lights file: it is a "
                               "directory; give a regular file")
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    scene.write_text('lights = "pipe.csv"\n' + SCENE_HEAD)
    assert error_of(scene) == f"{fifo}: cannot read lights file: it is a FIFO (named pipe); give a regular file"


def test_non_utf8_csv(tmp_path):
    msg = error_of(scene_with(tmp_path, b"x,y,z\n1,2,3\ncaf\xe9,1,2\n"))
    assert msg == f"{tmp_path / 'rig.csv'}:3: not UTF-8 (byte 15); save the file as UTF-8"


def test_memory_bound(tmp_path, monkeypatch):
    scene = scene_with(tmp_path, "x,y,z\n" + "1,2,3\n" * 1000)
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "100K")
    msg = error_of(scene)
    assert msg.startswith(f"{tmp_path / 'rig.csv'}: reading 1002 rows (5.9 KiB) of lights needs about ")
    assert "set CLPHONG_MAX_MEMORY" in msg
    np.savez(tmp_path / "rig.npz", x=np.zeros(1000), y=np.zeros(1000), z=np.zeros(1000))
    scene.write_text('lights = "rig.npz"\n' + SCENE_HEAD)
    assert error_of(scene).startswith(f"{tmp_path / 'rig.npz'}: reading 1000 lights needs about ")


def test_read_light_table_columns(tmp_path):
    (tmp_path / "r.csv").write_text(' type , x,y,z, group\npoint,1, 2,3 , "k"\n')
    t = read_light_table(str(tmp_path / "r.csv"))
    assert t.rows == 1 and sorted(t.numbers) == ["x", "y", "z"] and t.text["group"].tolist() == ["k"]
    assert t.lines.tolist() == [2] and t.numbers["z"].tolist() == [3.0]


def test_column_of():
    assert [column_of(p) for p in ("color[1]", "position", "attenuation[2]", "intensity", "direction")] \
        == ["g", "x, y, z", "c2", "intensity", "dx, dy, dz"]


def test_light_columns_refuses_environment_lights():
    from clphong.model.scene import Light

    with pytest.raises(ValueError, match="light 0 is 'environment'"):
        light_columns([Light("environment", file="sky.exr")])


# ------------------------------------------------------------------ property

_VALUES = st.one_of(
    st.sampled_from([0.0, -0.0, 1.0, -1.0, 0.5, 1e-40, 1e-3, 1e38, 3.5e38, 1e300, 45.0, 90.0, 91.0]),
    st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, width=64))
_GROUPS = st.sampled_from([None, "key", "fill", "diffuse", "1bad"])


@st.composite
def rigs(draw):
    """Rows every one of which gives exactly the keys its type takes in one layout of
    columns (so the file is well formed), with values that may break any value check."""
    n = draw(st.integers(1, 6))
    types = draw(st.lists(st.sampled_from(["point", "spot", "directional", "ambient"]),
                          min_size=n, max_size=n))
    watts = draw(st.booleans())
    color, att, angles, group = (draw(st.booleans()) for _ in range(4))
    rows = []
    for t in types:
        lt: dict = {"type": t}
        point = t in ("point", "spot")
        if point:
            lt["position"] = draw(st.lists(_VALUES, min_size=3, max_size=3))
        if t in ("spot", "directional"):
            lt["direction"] = draw(st.lists(_VALUES, min_size=3, max_size=3))
        if color:
            lt["color"] = draw(st.lists(_VALUES, min_size=3, max_size=3))
        if watts and point:
            lt["power"] = draw(_VALUES)
        elif not watts:
            lt["intensity"] = draw(_VALUES)
            if att and point:
                lt["attenuation"] = draw(st.lists(_VALUES, min_size=3, max_size=3))
        if angles and t == "spot":
            lt["inner_angle"], lt["outer_angle"] = draw(_VALUES), draw(_VALUES)
        if group:
            g = draw(_GROUPS)
            if g is not None:
                lt["group"] = g
        rows.append(lt)
    return rows


#: Each column's key, and the index of its component in a vector key.
_CELL = {"type": ("type", None), "x": ("position", 0), "y": ("position", 1), "z": ("position", 2),
         "dx": ("direction", 0), "dy": ("direction", 1), "dz": ("direction", 2),
         "r": ("color", 0), "g": ("color", 1), "b": ("color", 2), "intensity": ("intensity", None),
         "power": ("power", None), "c0": ("attenuation", 0), "c1": ("attenuation", 1),
         "c2": ("attenuation", 2), "inner_angle": ("inner_angle", None),
         "outer_angle": ("outer_angle", None), "group": ("group", None)}


def _cell(lt: dict, c: str):
    key, i = _CELL[c]
    if key not in lt:
        return None
    return lt[key] if i is None else lt[key][i]


def _csv_of(rows) -> str:
    """The rows as CSV, written here cell by cell (numbers as repr, which reads back exactly)."""
    assert set(_CELL) == set(COLUMNS)
    cols = [c for c in COLUMNS if any(_cell(lt, c) is not None for lt in rows)]
    lines = [",".join(cols)]
    for lt in rows:
        cells = [_cell(lt, c) for c in cols]
        lines.append(",".join("" if v is None else v if isinstance(v, str) else repr(float(v))
                              for v in cells))
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("rigs")


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rigs())
def test_rows_are_checked_as_tables(folder, rows):
    """A lights file is accepted exactly when the same lights as [[light]] tables are,
    with the same lights; when refused, it names the same row and the same column, and
    (past the structural checks, which the rows here all pass) says the same."""
    path = folder / "rig.csv"
    path.write_text(_csv_of(rows))
    try:
        ref = quiet(parse_scene, {"material": MATERIAL, "light": rows}, "s.toml")
    except SceneError as exc:
        ref = exc
    try:
        got = quiet(parse_scene, {"material": MATERIAL, "lights": str(path)}, "s.toml")
    except SceneError as exc:
        got = exc
    if isinstance(ref, SceneError):
        assert isinstance(got, SceneError), (str(ref), rows)
        m = re.match(r"s\.toml: light\[(\d+)\]\.(\S+): (.*?)(?: \(light\[\d+\] is the \S+ \[\[light\]\]\))?$",
                     str(ref))
        if m is None:                    # a whole-scene check (k_a x the ambient sum)
            assert str(got) == str(ref)
            return
        row, key, problem = int(m.group(1)), m.group(2), m.group(3)
        assert str(got) == f"{path}: row {row} (line {row + 2}): {column_of(key)}: {problem}"
    else:
        assert not isinstance(got, SceneError), (str(got), rows)
        assert got.lights == ref.lights
        for k in ref.light_arrays:
            assert np.array_equal(got.light_arrays[k], ref.light_arrays[k], equal_nan=True), k


def test_property_examples_reach_both_outcomes():
    """The strategy makes rigs that tables accept and rigs they refuse (so the property
    can fail either way)."""
    def accepted(rows):
        try:
            quiet(parse_scene, {"material": MATERIAL, "light": rows})
            return True
        except SceneError:
            return False

    settings_ = settings(max_examples=500, database=None)
    assert accepted(find(rigs(), lambda rows: accepted(rows) and len(rows) > 2, settings=settings_))
    assert not accepted(find(rigs(), lambda rows: not accepted(rows), settings=settings_))


def test_readme_example_is_a_valid_lights_file(tmp_path):
    """docs/lighting.md's lights-file example reads as the lights it shows."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "lighting.md").read_text(encoding="utf-8")
    section = text[text.index("### Many lights: a lights file"):]
    body = re.search(r"\n```\n(type,.*?)```", section, re.S).group(1)
    lts = quiet(load_scene, scene_with(tmp_path, body)).lights
    assert [lt.type for lt in lts] == ["point", "spot", "directional", "ambient"]
    assert (lts[0].group, lts[0].attenuation, lts[1].outer_angle) == ("key", (1.0, 0.1, 0.05), 25.0)


def test_bench_scenes_in_each_format_are_the_same_lights(tmp_path):
    """clphong.tools.commands.write_scene: the wide scene as tables, CSV and .npz."""
    from clphong.tools.commands import write_scene

    scenes = [quiet(load_scene, write_scene(tmp_path, 64, f)) for f in ("toml", "csv", "npz")]
    assert len(scenes[0].lights) == 65
    assert scenes[1].lights == scenes[0].lights == scenes[2].lights
    assert scenes[2].material == scenes[0].material and scenes[2].camera == scenes[0].camera
