"""Tests of tmr.world.maps: ROS map_server / Nav2 maps read with PyYAML and Pillow, GeoJSON and WKT, and their errors.

The occupancy of every pixel is checked against the map_server definition written out here (shade = value / full
scale, occupancy 1 - shade or shade with negate, thresholds), not against the loader's own code.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from PIL import Image
from shapely.geometry import Point, box

from tmr.errors import MapError
from tmr.world.environment import Environment
from tmr.world.maps import (
    load_environment,
    load_map,
    occupancy,
    read_map_image,
    read_map_yaml,
    saver_grey_reads_free,
)

R = 0.5  # safety radius [m]


# ------------------------------------------------------------------------------------------------------ ROS
# maps
def _write_pgm_p5(path: Path, img: np.ndarray, maxval: int = 255, comment: bool = True) -> None:
    h, w = img.shape
    header = b"P5\n" + (b"# CREATOR: test\n" if comment else b"") + f"{w} {h}\n{maxval}\n".encode()
    dtype = ">u2" if maxval > 255 else "u1"
    path.write_bytes(header + img.astype(dtype).tobytes())


def _ros_image() -> np.ndarray:
    """40 x 60 pixels (2 m x 3 m at 5 cm): white (free), a black 10 x 10 block, a grey (unknown) strip."""
    img = np.full((40, 60), 254, dtype=np.int64)
    img[5:15, 20:30] = 0  # occupied: rows 5..14 from the top, columns 20..29
    img[30:40, 50:60] = 205  # unknown (trinary grey)
    return img


def _check_ros_env(env: Environment) -> None:
    # origin (-1, -0.5): the image covers x in [-1, 2], y in [-0.5, 1.5]
    assert env.bounds == pytest.approx((-1.0, -0.5, 2.0, 1.5))
    # occupied block: x in [-1 + 20*0.05, -1 + 30*0.05] = [0, 0.5], y from 1.5 - 15*0.05 = 0.75 to 1.25
    assert env.obstacles.area == pytest.approx(0.25 + 0.25, rel=1e-9)  # block + unknown strip (0.5 m x 0.5 m)
    assert env.obstacles.covers(box(0.0, 0.75, 0.5, 1.25))
    assert env.obstacles.covers(box(1.5, -0.5, 2.0, 0.0))  # unknown cells are obstacles
    # nearest: the grown corner of the block at (0.5, 0.75)
    np.testing.assert_allclose(env.exact_clearance([[1.0, 0.4]]), [math.hypot(0.5, 0.35) - R], atol=1e-3)


def test_ros_map_p5(tmp_path: Path) -> None:
    _write_pgm_p5(tmp_path / "map.pgm", _ros_image())
    (tmp_path / "map.yaml").write_text(
        "# map_saver output\nimage: map.pgm\nresolution: 0.050000\norigin: [-1.0, -0.5, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n"
    )
    env = load_environment(tmp_path / "map.yaml")
    _check_ros_env(env)
    assert env.source == tmp_path / "map.yaml"


def test_ros_map_p2_negate_block_list(tmp_path: Path) -> None:
    img = 255 - _ros_image()  # negated image: 255 - v
    h, w = img.shape
    rows = "\n".join(" ".join(str(v) for v in row) for row in img)
    (tmp_path / "m.pgm").write_text(f"P2\n# ascii\n{w} {h}\n255\n{rows}\n")
    (tmp_path / "m.yaml").write_text(
        'image: "m.pgm"   # quoted\nresolution: 0.05\norigin:\n  - -1.0\n  - -0.5\n  - 0.0\nnegate: 1\n'
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    _check_ros_env(load_environment(tmp_path / "m.yaml"))


def test_ros_map_16bit_and_png(tmp_path: Path) -> None:
    import matplotlib.image as mpimg

    img = _ros_image()
    _write_pgm_p5(tmp_path / "m16.pgm", img * 257, maxval=65535, comment=False)
    yaml = "resolution: 0.05\norigin: [-1.0, -0.5, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    (tmp_path / "m16.yaml").write_text("image: m16.pgm\n" + yaml)
    _check_ros_env(load_environment(tmp_path / "m16.yaml"))
    mpimg.imsave(tmp_path / "m.png", img / 255.0, cmap="gray", vmin=0.0, vmax=1.0)
    (tmp_path / "mp.yaml").write_text("image: m.png\n" + yaml)
    _check_ros_env(load_environment(tmp_path / "mp.yaml"))


def test_ros_map_yaw_rotates(tmp_path: Path) -> None:
    _write_pgm_p5(tmp_path / "map.pgm", _ros_image())
    (tmp_path / "map.yaml").write_text(f"image: map.pgm\nresolution: 0.05\norigin: [0.0, 0.0, {math.pi / 2}]\n")
    env = load_environment(tmp_path / "map.yaml")
    # rotated by +90 deg about the origin: the 3 m x 2 m image covers x in [-2, 0], y in [0, 3]
    assert env.bounds == pytest.approx((-2.0, 0.0, 0.0, 3.0), abs=1e-9)
    # the block (image x in [1, 1.5], y in [1.25, 1.75]) maps to x in [-1.75, -1.25], y in [1, 1.5]
    assert env.obstacles.buffer(1e-9).covers(box(-1.75, 1.0, -1.25, 1.5))


@pytest.mark.parametrize(
    ("yaml", "image", "match"),
    [
        ("this is: not: [valid\n", None, "line 1"),
        ("just garbage without colon\n", None, "expected 'key: value'"),
        ("image: map.pgm\nresolution: 0.05\n", b"P5\n2 2\n255\n\x00\x00\x00\x00", "origin"),
        (
            "image: map.pgm\nresolution: -0.05\norigin: [0, 0, 0]\n",
            b"P5\n2 2\n255\n\x00\x00\x00\x00",
            "resolution",
        ),
        (
            "image: map.pgm\nresolution: abc\norigin: [0, 0, 0]\n",
            b"P5\n2 2\n255\n\x00\x00\x00\x00",
            "resolution",
        ),
        ("image: other.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", None, "other.pgm not found"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", b"not an image", "cannot read the map image"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", b"P5\nxx 2\n255\n", "cannot read the map image"),
        ("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", b"P5\n20 20\n255\n\x00\x00", "cannot read"),
        (
            "image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.9\n",
            b"P5\n2 2\n255\n" + bytes(4),
            "free_thresh",
        ),
        (
            "image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fancy\n",
            b"P5\n2 2\n255\n" + bytes(4),
            "mode",
        ),
        ("resolution: 0.05\norigin: [0, 0, 0]\nresolution: 0.1\n", None, "duplicate key"),
        ("", None, "empty map yaml"),
    ],
)
def test_ros_map_errors(tmp_path: Path, yaml: str, image: bytes | None, match: str) -> None:
    (tmp_path / "map.yaml").write_text(yaml)
    if image is not None:
        (tmp_path / "map.pgm").write_bytes(image)
    with pytest.raises(MapError, match=match) as info:
        load_environment(tmp_path / "map.yaml")
    assert "map." in str(info.value)  # names the file


def test_all_black_map_has_no_free_space(tmp_path: Path) -> None:
    _write_pgm_p5(tmp_path / "map.pgm", np.zeros((40, 40)))
    (tmp_path / "map.yaml").write_text("image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(MapError, match="no free space"):
        load_environment(tmp_path / "map.yaml")


# -------------------------------------------------------------------------------------------------- GeoJSON
# / WKT
def test_geojson_loader(tmp_path: Path) -> None:
    doc = {
        "type": "FeatureCollection",
        "bounds": [0, 0, 10, 8],
        "features": [
            {
                "type": "Feature",
                "properties": {"name": "block"},
                "geometry": {"type": "Polygon", "coordinates": [[[1, 1], [3, 1], [3, 2], [1, 2], [1, 1]]]},
            },
            {
                "type": "Feature",
                "properties": {"radius": 0.5},
                "geometry": {"type": "Point", "coordinates": [6, 4]},
            },
            {
                "type": "Feature",
                "properties": {"width": 0.2},
                "geometry": {"type": "LineString", "coordinates": [[8, 0], [8, 3]]},
            },
            {
                "type": "Feature",
                "properties": {},
                "geometry": {"type": "MultiPolygon", "coordinates": [[[[1, 6], [2, 6], [2, 7], [1, 6]]]]},
            },
            {"type": "Feature", "properties": {}, "geometry": None},
        ],
    }
    (tmp_path / "m.geojson").write_text(json.dumps(doc))
    env = load_environment(tmp_path / "m.geojson")
    assert env.bounds == (0.0, 0.0, 10.0, 8.0)
    assert env.obstacles.area == pytest.approx(2.0 + math.pi * 0.25 + 0.6 + 0.5, rel=1e-3)
    np.testing.assert_allclose(env.exact_clearance([[6.0, 6.0]]), [2.0 - 1.0], atol=1e-3)
    np.testing.assert_allclose(env.exact_clearance([[9.0, 1.5]]), [0.9 - R], atol=1e-9)
    # explicit bounds win over the file's
    assert load_environment(tmp_path / "m.geojson", bounds=(0, 0, 12, 9)).bounds == (0.0, 0.0, 12.0, 9.0)
    # a bare geometry needs explicit bounds
    (tmp_path / "g.json").write_text(json.dumps(doc["features"][0]["geometry"]))
    with pytest.raises(MapError, match="no room bounds"):
        load_environment(tmp_path / "g.json")
    assert load_environment(tmp_path / "g.json", bounds=(0, 0, 5, 5)).obstacles.area == pytest.approx(2.0)


def test_wkt_loader(tmp_path: Path) -> None:
    (tmp_path / "a.wkt").write_text(
        "# two obstacles\n# bounds: 0 0 10 10\nPOLYGON ((1 1, 3 1, 3 3, 1 3, 1 1))\nLINESTRING (5 0, 5 6)\n"
    )
    env = load_environment(tmp_path / "a.wkt")
    assert env.bounds == (0.0, 0.0, 10.0, 10.0)
    assert env.obstacles.area == pytest.approx(4.0)
    np.testing.assert_allclose(env.exact_clearance([[5.0, 7.0]]), [0.5], atol=2e-3)  # above the grown line end
    (tmp_path / "b.wkt").write_text("GEOMETRYCOLLECTION (\n  POLYGON ((1 1, 3 1, 3 3, 1 3, 1 1)),\n  POINT (7 7))\n")
    env = load_environment(tmp_path / "b.wkt", bounds=(0, 0, 10, 10))
    assert env.exact_clearance([7.0, 7.0]) == pytest.approx(-R, abs=1e-3)  # 64-gon disc
    with pytest.raises(MapError, match="no room bounds"):
        load_environment(tmp_path / "b.wkt")


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [
        ("bad.geojson", "{not json", "not valid JSON"),
        (
            "bad.geojson",
            '{"type": "FeatureCollection", "bounds": [0, 0, 5, 5], "features": [{"type": "Feature", '
            '"properties": {"name": "bow"}, "geometry": {"type": "Polygon", "coordinates": '
            "[[[0, 0], [2, 2], [2, 0], [0, 2], [0, 0]]]}}]}",
            r"invalid geometry.*Self-intersection",
        ),
        (
            "bad.geojson",
            '{"type": "FeatureCollection", "bounds": [0, 0, 5, 5], "features": [{"type": "Feature", '
            '"properties": {"radius": -1}, "geometry": {"type": "Point", "coordinates": [1, 1]}}]}',
            "radius",
        ),
        ("bad.geojson", '{"type": "FeatureCollection", "bounds": [0, 0, 5], "features": []}', "bounds"),
        ("bad.geojson", '{"type": "Topology"}', "unsupported geometry type"),
        ("bad.geojson", "[1, 2]", "not a GeoJSON object"),
        ("bad.wkt", "# bounds: 0 0 10 10\nPOLYGON ((1 1, 3 1, 3 3\n", "not valid WKT"),
        ("bad.wkt", "# bounds: 0 0 10 10\nPOLYGON ((0 0, 2 2, 2 0, 0 2, 0 0))\n", "invalid geometry"),
        ("map.txt", "whatever", "unknown map format"),
        ("map.pgm", "P5", "yaml"),
    ],
)
def test_vector_map_errors(tmp_path: Path, name: str, text: str, match: str) -> None:
    (tmp_path / name).write_text(text)
    with pytest.raises(MapError, match=match) as info:
        load_environment(tmp_path / name)
    assert name in str(info.value)


def test_missing_map_file(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="not found") as info:
        load_environment(tmp_path / "nope.yaml")
    assert "nope.yaml" in str(info.value)


# ----------------------------------------------------------------------------------------------------- map_server
# conventions, written with Pillow
def _map_server_reference(values: np.ndarray, full: float, negate: bool, occ_th: float, free_th: float, mode: str):
    """Cell states by the map_server definition, pixel by pixel: 100 occupied, 0 free, -1 unknown, or the scaled
    value (scale) / the raw percent (raw)."""
    out = np.empty(values.shape, dtype=int)
    for idx, v in np.ndenumerate(values):
        shade = float(v) / full
        occ = shade if negate else 1.0 - shade
        if mode == "raw":
            out[idx] = int(v) if int(v) <= 100 else -1
        elif occ > occ_th:
            out[idx] = 100
        elif occ < free_th:
            out[idx] = 0
        elif mode == "scale":
            out[idx] = round(1 + 98 * (occ - free_th) / (occ_th - free_th))
        else:
            out[idx] = -1
    return out


def _turtlebot3_world(tmp_path: Path) -> Path:
    """A map like map_saver's TurtleBot3-world map: 400 x 400 px at 0.05 m (20 m x 20 m), origin (-10, -10),
    unknown (205) everywhere but a 5 m x 5 m walled arena round (−0.5, 0.5) with nine 0.3 m pillars."""
    img = np.full((400, 400), 205, dtype=np.uint8)
    # arena: x in [-3, 2], y in [-2, 3] -> columns (x + 10) / 0.05, rows (10 - y) / 0.05 from the top
    c0, c1, r0, r1 = 140, 240, 140, 240
    img[r0:r1, c0:c1] = 254
    img[r0 : r0 + 3, c0:c1] = 0
    img[r1 - 3 : r1, c0:c1] = 0
    img[r0:r1, c0 : c0 + 3] = 0
    img[r0:r1, c1 - 3 : c1] = 0
    for px in (-2.0, -0.5, 1.0):
        for py in (-1.0, 0.5, 2.0):
            if (px, py) == (-0.5, 0.5):
                continue  # the middle is kept free
            cx, cy = (px + 10) / 0.05, (10 - py) / 0.05
            yy, xx = np.mgrid[0:400, 0:400]
            img[(xx + 0.5 - cx) ** 2 + (yy + 0.5 - cy) ** 2 <= 3.0**2] = 0
    Image.fromarray(img, mode="L").save(tmp_path / "turtlebot3_world.pgm")
    (tmp_path / "turtlebot3_world.yaml").write_text(
        "image: turtlebot3_world.pgm\nmode: trinary\nresolution: 0.05\norigin: [-10, -10, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return tmp_path / "turtlebot3_world.yaml"


def test_turtlebot3_like_map(tmp_path: Path) -> None:
    path = _turtlebot3_world(tmp_path)
    meta = read_map_yaml(path)
    assert meta.origin == (-10.0, -10.0, 0.0) and meta.resolution == 0.05 and meta.free_thresh == 0.196
    shade, alpha = read_map_image(meta.image)
    assert alpha is None and shade.shape == (400, 400)
    pixels = np.asarray(Image.open(meta.image))
    np.testing.assert_array_equal(
        occupancy(meta, shade, alpha), _map_server_reference(pixels, 255, False, 0.65, 0.196, "t")
    )
    geo = load_map(path)
    assert geo.bounds == pytest.approx((-10.0, -10.0, 10.0, 10.0))
    # the known free cells: inside the 3-px walls of the arena x in [-3, 2], y in [-2, 3]
    assert geo.known_free == pytest.approx((-3.0 + 0.15, -2.0 + 0.15, 2.0 - 0.15, 3.0 - 0.15))
    env = load_environment(path, safety_radius=0.15)
    assert env.known_free == geo.known_free
    # every pixel centre: inside the obstacles unless its cell is known free (sampled away from cell edges)
    rows, cols = np.mgrid[0:400:7, 0:400:7]
    xs, ys = -10 + (cols + 0.5) * 0.05, 10 - (rows + 0.5) * 0.05
    free_ref = _map_server_reference(pixels[rows, cols], 255, False, 0.65, 0.196, "t") == 0
    np.testing.assert_array_equal(~shapely.contains_xy(env.obstacles, xs, ys), free_ref)
    # the middle of the arena, 0.45 m from the nearest pillar edge: free with r = 0.15, clearance exact
    assert env.exact_clearance([-0.5, 0.5]) == pytest.approx(1.5 - 0.15 - 0.15, abs=0.03)


def test_nav2_yaml_with_comments_and_extra_keys(tmp_path: Path) -> None:
    img = np.array([[0, 100, 200, 254], [254, 254, 128, 10]], dtype=np.uint8)
    Image.fromarray(img).save(tmp_path / "my map.png")
    (tmp_path / "nav2.yaml").write_text(
        "# Nav2 map_server map\n"
        "---\n"
        "image: 'my map.png'   # quoted, with a space\n"
        "mode: scale\n"
        "resolution: 0.5\n"
        "origin:\n  - -1.0   # x\n  - 2.5\n  - 0.0\n"
        "negate: false\n"
        "occupied_thresh: 0.65\n"
        "free_thresh: 0.196\n"
        "map_name: lab   # extra keys are ignored\n"
        "extra: {a: 1, b: [1, 2]}\n"
    )
    meta = read_map_yaml(tmp_path / "nav2.yaml")
    assert meta.image == tmp_path / "my map.png" and meta.origin == (-1.0, 2.5, 0.0) and meta.mode == "scale"
    grid = occupancy(meta, *read_map_image(meta.image))
    np.testing.assert_array_equal(grid, _map_server_reference(img, 255, False, 0.65, 0.196, "scale"))
    geo = load_map(tmp_path / "nav2.yaml")
    assert geo.bounds == pytest.approx((-1.0, 2.5, 1.0, 3.5))
    # free cells: (row 0, col 3), (row 1, cols 0, 1); everything else (occupied or scaled 1..99) is an obstacle
    assert geo.obstacles.area == pytest.approx(5 * 0.25)
    assert not geo.obstacles.contains(Point(0.75, 3.25)) and not geo.obstacles.contains(Point(-0.75, 2.75))


@pytest.mark.parametrize("negate", [False, True])
def test_modes_against_the_definition(tmp_path: Path, negate: bool) -> None:
    rng = np.random.default_rng(3)
    values = rng.integers(0, 256, size=(12, 9)).astype(np.uint8)
    Image.fromarray(values).save(tmp_path / "m.bmp")
    for mode in ("trinary", "scale", "raw"):
        (tmp_path / "m.yaml").write_text(
            f"image: m.bmp\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: {int(negate)}\nmode: {mode}\n"
            "occupied_thresh: 0.7\nfree_thresh: 0.3\n"
        )
        meta = read_map_yaml(tmp_path / "m.yaml")
        got = occupancy(meta, *read_map_image(meta.image), keep_saver_unknown=False)
        np.testing.assert_array_equal(got, _map_server_reference(values, 255, negate, 0.7, 0.3, mode), err_msg=mode)


def test_16bit_png_and_pgm_read_at_full_scale(tmp_path: Path) -> None:
    values = np.array([[0, 1000, 32768, 65535]], dtype=np.uint16)
    Image.fromarray(values).save(tmp_path / "m16.png")
    shade, alpha = read_map_image(tmp_path / "m16.png")
    np.testing.assert_allclose(shade, values / 65535.0)
    # a PGM with maxval 1000: the value over its maxval (Pillow scales it, map_server divides by maxval)
    raw = np.array([[0, 500, 1000]], dtype=">u2")
    (tmp_path / "m.pgm").write_bytes(b"P5\n3 1\n1000\n" + raw.tobytes())
    np.testing.assert_allclose(read_map_image(tmp_path / "m.pgm")[0], [[0.0, 0.5, 1.0]], atol=1e-4)


def test_scale_mode_transparent_pixels_are_unknown(tmp_path: Path) -> None:
    rgba = np.zeros((2, 2, 4), dtype=np.uint8)
    rgba[..., :3] = 254
    rgba[..., 3] = 255
    rgba[0, 1, 3] = 0  # transparent
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "a.png")
    (tmp_path / "a.yaml").write_text("image: a.png\nresolution: 1\norigin: [0, 0, 0]\nmode: scale\n")
    meta = read_map_yaml(tmp_path / "a.yaml")
    np.testing.assert_array_equal(occupancy(meta, *read_map_image(meta.image)), [[0, -1], [0, 0]])


def test_environment_has_no_file_loader() -> None:
    """Map files are the loader's job: the environment answers geometric queries only."""
    import tmr.world.environment

    assert not hasattr(Environment, "from_file")
    source = Path(tmr.world.environment.__file__).read_text()
    assert "yaml" not in source.lower().replace("map_server", "") or "import yaml" not in source
    assert "PGM" not in source and "def read_pgm" not in source


def test_nav2_legacy_free_thresh_keeps_the_saver_grey_unknown(tmp_path, capsys, caplog):
    """Nav2's map_saver wrote trinary maps with free_thresh 0.25 (until navigation2 #5278): by the thresholds its
    unknown grey 205 (occupancy 0.196) would be free and the 20 m x 20 m unknown area plannable; it stays unknown."""
    path = _turtlebot3_world(tmp_path)
    path.write_text(path.read_text().replace("free_thresh: 0.196", "free_thresh: 0.25"))
    meta = read_map_yaml(path)
    assert meta.free_thresh == 0.25 and saver_grey_reads_free(meta)
    values = np.array([[205, 210, 254, 0, 180]], dtype=np.uint8)  # 210: occupancy 0.176 < 0.25, free by definition
    shade = values / 255.0
    np.testing.assert_array_equal(occupancy(meta, shade, None), [[-1, 0, 0, 100, -1]])
    np.testing.assert_array_equal(occupancy(meta, shade, None, keep_saver_unknown=False), [[0, 0, 0, 100, -1]])
    geo = load_map(path)
    assert geo.known_free == pytest.approx((-2.85, -1.85, 1.85, 2.85))  # the arena, as with free_thresh 0.196
    # through the tmr logger: on stderr once a command set it up, else in pytest's log capture
    assert "kept unknown" in capsys.readouterr().err + caplog.text
    (tmp_path / "ok").mkdir()
    assert not saver_grey_reads_free(read_map_yaml(_turtlebot3_world(tmp_path / "ok")))  # free_thresh 0.196
