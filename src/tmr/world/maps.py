"""Map files → geometry: ROS ``map_server`` / Nav2 occupancy maps, GeoJSON and WKT.

The loader turns a file into shapely obstacles and a room rectangle; :class:`tmr.world.environment.Environment` then
answers the geometric queries (clearance, free space). Data flows one way: this module imports the environment,
never the reverse. :func:`load_environment` does both steps.

* ROS maps: the YAML is read with PyYAML (comments, quoting, flow or block lists, extra Nav2 keys such as
  ``free_thresh``/``occupied_thresh``/``mode`` or unknown ones all as YAML defines them), the image with Pillow
  (PGM P2/P5, PNG, BMP, 8 or 16 bit, greyscale, palette or colour, with or without alpha). The cell occupancy follows
  the map_server conventions (ROS ``map_server`` / Nav2 ``nav2_map_server`` ``map_io``): the shade s ∈ [0, 1] is
  the pixel value (colour channels averaged) over the image's full scale; the occupancy is p = 1 − s, or p = s with
  ``negate: 1``; ``mode: trinary`` and ``scale``: occupied for p > ``occupied_thresh``, free for
  p < ``free_thresh``, unknown in between (``scale`` also marks transparent pixels unknown); ``mode: raw``: the pixel
  value v ∈ 0..255 is the occupancy in percent, v > 100 unknown. tmr plans only in **known free** cells: occupied
  and unknown cells are obstacles (conservative). ``origin: [x, y, yaw]`` is the pose of the image's lower-left
  pixel [m, m, rad]; a yaw rotates the map about that corner. One exception to the thresholds: a trinary map whose
  ``free_thresh`` exceeds 0.196 (Nav2's map_saver wrote 0.25 until 2025) would read map_saver's unknown grey 205 as
  free; those pixels are kept unknown, with a warning (:func:`saver_grey_reads_free`).
* GeoJSON / WKT: see :func:`load_map`.
* Bundled maps (:data:`BUNDLED_MAP_DIR`, ``src/tmr/world/maps/``, sources in its README): a bare file name that is not
  a file in the current directory, e.g. ``--map turtlebot3_world.yaml``, names one of them (:func:`resolve_map_path`).
"""

from __future__ import annotations

import json
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import shapely.affinity
import shapely.errors
from numpy.typing import NDArray
from shapely.geometry import box
from shapely.geometry.base import BaseGeometry

from tmr.errors import MapError
from tmr.world.environment import (
    DEFAULT_RESOLUTION,
    DEFAULT_SAFETY_RADIUS,
    QUAD_SEGS,
    Bounds,
    Environment,
    LowObstacle,
    check_bounds,
    check_geometry,
)

__all__ = [
    "BUNDLED_MAP_DIR",
    "SAVER_UNKNOWN",
    "bundled_maps",
    "resolve_map_path",
    "saver_grey_reads_free",
    "MAP_SUFFIXES",
    "IMAGE_SUFFIXES",
    "MapGeometry",
    "RosMapMeta",
    "load_environment",
    "load_map",
    "read_map_yaml",
    "read_map_image",
    "occupancy",
]

MAP_SUFFIXES = (".yaml", ".yml", ".geojson", ".json", ".wkt")
IMAGE_SUFFIXES = (".pgm", ".png", ".bmp")
MODES = ("trinary", "scale", "raw")


@dataclass(frozen=True)
class MapGeometry:
    """What a map file holds: ``obstacles`` (shapely, raw, not grown), the room ``bounds`` (xmin, ymin, xmax, ymax)
    [m] (None when the file does not say), for an occupancy map ``known_free``, the bounding box [m] of its
    known free cells (None otherwise), and the ``low_obstacles`` (GeoJSON features with a ``"height"``)."""

    obstacles: BaseGeometry | list[BaseGeometry]
    bounds: Bounds | None
    known_free: Bounds | None = None
    low_obstacles: tuple[LowObstacle, ...] = ()


@dataclass(frozen=True)
class RosMapMeta:
    """The keys of a map_server YAML that tmr uses (others, e.g. Nav2's extra keys, are ignored)."""

    image: Path  #: the image file, resolved against the YAML's folder
    resolution: float  #: m per pixel
    origin: tuple[float, float, float]  #: lower-left pixel pose x [m], y [m], yaw [rad]
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str  #: trinary, scale or raw


#: Maps shipped with tmr (ROS map_server .yaml + image), each with its source in the directory's README.md.
BUNDLED_MAP_DIR = Path(__file__).resolve().parent / "maps"


def bundled_maps() -> list[str]:
    """File names of the bundled maps' YAML files (``turtlebot3_world.yaml``, ...)."""
    return sorted(f.name for f in BUNDLED_MAP_DIR.glob("*.yaml"))


def resolve_map_path(path: str | Path) -> Path:
    """``path`` itself if it exists; else, if it is a bare file name (no directory part) of a bundled map
    (:func:`bundled_maps`), that map's file in :data:`BUNDLED_MAP_DIR`; else ``path`` unchanged (its reader then says
    it is not found)."""
    p = Path(path)
    if p.exists() or p.parent != Path("."):
        return p
    bundled = BUNDLED_MAP_DIR / p.name
    return bundled if bundled.is_file() and p.name in bundled_maps() else p


def load_environment(
    path: str | Path,
    bounds: Any = None,
    safety_radius: float = DEFAULT_SAFETY_RADIUS,
    resolution: float = DEFAULT_RESOLUTION,
) -> Environment:
    """:func:`load_map` then an :class:`~tmr.world.environment.Environment` with obstacles grown by ``safety_radius`` r
    [m] (``resolution`` [m]: cell of its distance field). ``bounds`` (xmin, ymin, xmax, ymax) [m] overrides the
    file's room; raises MapError naming the file and the problem. A bundled map may be named by its bare file name
    (:func:`resolve_map_path`)."""
    p = resolve_map_path(path)
    geo = load_map(p)
    room = bounds if bounds is not None else geo.bounds
    if room is None:
        raise MapError(
            f"{p}: no room bounds: give them (the command line's --bounds XMIN,YMIN,XMAX,YMAX, a scenario's [map] "
            f"bounds = [xmin, ymin, xmax, ymax], Python's bounds=) or put them in the file (GeoJSON: top-level "
            f"\"bounds\" member; WKT: a '# bounds: xmin ymin xmax ymax' comment)"
        )
    env = Environment(geo.obstacles, room, safety_radius, resolution, source=p, low_obstacles=geo.low_obstacles)
    env.known_free = geo.known_free
    return env


def load_map(path: str | Path) -> MapGeometry:
    """Read a map file; raises MapError naming the file and the problem.

    * ``.yaml``/``.yml``: ROS ``map_server`` / Nav2 map metadata (``image``, ``resolution``, ``origin: [x, y, yaw]``,
      ``negate``, ``occupied_thresh``, ``free_thresh``, ``mode``) and its image (PGM, PNG or BMP); the room is the
      image footprint; occupied and unknown cells are obstacles.
    * ``.geojson``/``.json``: a FeatureCollection, Feature, GeometryCollection or bare geometry. Polygons
      and multipolygons are obstacles; a Point (or MultiPoint) with a ``radius`` property [m] is a disc; a
      LineString with a ``width`` property [m] is a wall of that thickness (flat ends); points/lines
      without them are zero-thickness obstacles. The room is a top-level ``"bounds": [xmin, ymin, xmax, ymax]``
      member of the document, if any. A feature with a numeric ``"height"`` property [m] (> 0) is a **low
      obstacle** of that height (:class:`~tmr.world.environment.LowObstacle`: the robots avoid it, a tether may pass
      over it); it needs an area (a polygon, a point with a radius or a line with a width). Features without it are
      tall obstacles.
    * ``.wkt``: one WKT geometry (e.g. a GEOMETRYCOLLECTION or MULTIPOLYGON), or one per line; ``#``
      starts a comment line; a comment ``# bounds: xmin ymin xmax ymax`` gives the room.

    A bare file name that is not in the current directory may name a bundled map (:func:`resolve_map_path`).
    """
    p = resolve_map_path(path)
    if not p.exists():
        raise MapError(f"{p}: map file not found (bundled maps, by bare file name: {', '.join(bundled_maps())})")
    if not p.is_file():
        raise MapError(f"{p}: is a directory, not a map file" if p.is_dir() else f"{p}: not a regular file")
    suffix = p.suffix.lower()
    if suffix in (".yaml", ".yml"):
        return _load_ros_map(p)
    if suffix in (".geojson", ".json"):
        return _load_geojson(p)
    if suffix == ".wkt":
        return MapGeometry(*_load_wkt(p))
    if suffix in IMAGE_SUFFIXES:
        raise MapError(f"{p}: give the ROS map_server .yaml file that describes this image (resolution, origin)")
    raise MapError(f"{p}: unknown map format {suffix!r}; supported: {', '.join(MAP_SUFFIXES)}")


# ------------------------------------------------------------------------------------------------------------
# ROS map_server / Nav2 maps
# ------------------------------------------------------------------------------------------------------------
def _yaml_loader() -> Any:
    """PyYAML's SafeLoader that refuses duplicate keys (YAML forbids them; PyYAML would keep the last)."""
    import yaml

    class _Loader(yaml.SafeLoader):
        pass

    def mapping(loader: Any, node: Any, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = loader.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return loader.construct_mapping(node, deep=deep)

    _Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    return _Loader


def _number(meta: dict[str, Any], key: str, where: str, default: float | None = None) -> float:
    if key not in meta or meta[key] is None:
        if default is None:
            raise MapError(f"{where}: missing required key {key!r}")
        return default
    v = meta[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise MapError(f"{where}: {key} must be a finite number, got {v!r}")
    return float(v)


def read_map_yaml(path: str | Path) -> RosMapMeta:
    """Read and check a map_server / Nav2 map YAML with PyYAML; MapError names the file, the line and the key."""
    import yaml

    path = Path(path)
    where = str(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise MapError(f"{path}: not a text file (map_server yaml expected)") from None
    except OSError as exc:
        raise MapError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        meta = yaml.load(text, Loader=_yaml_loader())  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f": line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise MapError(f"{path}{at}: not valid YAML: {problem}") from None
    if meta is None:
        raise MapError(f"{path}: empty map yaml (needs image, resolution, origin)")
    if not isinstance(meta, dict):
        raise MapError(
            f"{path}: expected 'key: value' lines (image, resolution, origin, ...), got {type(meta).__name__}"
        )
    image = meta.get("image")
    if not isinstance(image, str) or not image.strip():
        raise MapError(f"{where}: missing required key 'image' (path of the .pgm/.png, relative to the yaml)")
    res = _number(meta, "resolution", where)
    if res <= 0:
        raise MapError(f"{where}: resolution must be a positive number of metres per pixel, got {res}")
    origin = meta.get("origin")
    if (
        not isinstance(origin, list)
        or len(origin) not in (2, 3)
        or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in origin)
    ):
        raise MapError(f"{where}: origin must be a list [x, y, yaw] of finite numbers, got {origin!r}")
    negate = meta.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise MapError(f"{where}: negate must be 0 or 1, got {negate!r}")
    occ_th = _number(meta, "occupied_thresh", where, 0.65)
    free_th = _number(meta, "free_thresh", where, 0.196)
    if not 0.0 <= free_th <= occ_th <= 1.0:
        raise MapError(f"{where}: need 0 <= free_thresh <= occupied_thresh <= 1, got {free_th} and {occ_th}")
    mode = str(meta.get("mode", "trinary")).lower()
    if mode not in MODES:
        raise MapError(f"{where}: mode must be trinary, scale or raw, got {meta.get('mode')!r}")
    img_path = Path(image.strip())
    if not img_path.is_absolute():
        img_path = path.parent / img_path
    return RosMapMeta(
        image=img_path,
        resolution=res,
        origin=(float(origin[0]), float(origin[1]), float(origin[2]) if len(origin) == 3 else 0.0),
        negate=bool(negate),
        occupied_thresh=occ_th,
        free_thresh=free_th,
        mode=mode,
    )


def read_map_image(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Read a map image with Pillow → (shade, alpha), both (height, width) in [0, 1], row 0 the top of the image.

    The shade is the pixel value over the image's full scale (255 for 8 bit, 65535 for 16 bit; Pillow scales a
    PGM's maxval to it), colour channels averaged as map_server does; ``alpha`` is None for an opaque mode.
    """
    from PIL import Image, UnidentifiedImageError

    p = Path(path)
    try:
        with Image.open(p) as im:
            im.load()
            mode = im.mode
            if mode == "P":  # palette: expand to its colours (and transparency)
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
                mode = im.mode
            elif mode == "1":
                im = im.convert("L")
                mode = "L"
            arr = np.asarray(im)
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise MapError(f"{p}: cannot read the map image: {exc}") from None
    alpha = None
    if mode in ("L", "RGB", "LA", "RGBA"):
        scale = 255.0
        if mode in ("LA", "RGBA"):
            alpha = arr[..., -1].astype(float) / scale
            arr = arr[..., :-1]
        shade = arr.astype(float) / scale
        if shade.ndim == 3:
            shade = shade.mean(axis=-1)
    elif mode.startswith("I"):  # 16-bit greyscale ("I;16", "I;16B", "I")
        shade = np.clip(arr.astype(float) / 65535.0, 0.0, 1.0)
    else:
        raise MapError(f"{p}: unsupported image mode {mode!r}; save the map as 8- or 16-bit greyscale or RGB")
    if shade.ndim != 2 or shade.size == 0:
        raise MapError(f"{p}: the map image has no pixels")
    return shade, alpha


#: The grey map_saver writes for an unknown cell in trinary mode (occupancy 1 - 205/255 = 0.196).
SAVER_UNKNOWN = 205


def saver_grey_reads_free(meta: RosMapMeta) -> bool:
    """Whether map_saver's unknown grey would load as *free* under this YAML: a trinary map with ``free_thresh`` above
    0.196, as Nav2's map_saver wrote them (its default 0.25) before it fixed the trinary thresholds (navigation2
    PR #5278, 2025). Unknown space read as free would let a plan run through unmapped space."""
    return meta.mode == "trinary" and not meta.negate and 1.0 - SAVER_UNKNOWN / 255.0 < meta.free_thresh


def occupancy(
    meta: RosMapMeta,
    shade: NDArray[np.float64],
    alpha: NDArray[np.float64] | None,
    *,
    keep_saver_unknown: bool = True,
) -> NDArray[np.int8]:
    """Cell states as map_server gives them in the OccupancyGrid: 100 occupied, 0 free, -1 unknown; ``scale`` mode
    gives the values between as 1..99 and ``raw`` the pixel value itself (percent).

    ``keep_saver_unknown``: when :func:`saver_grey_reads_free`, pixels of exactly map_saver's unknown grey (205)
    stay unknown (-1) instead of free; every other pixel follows the thresholds."""
    occ = shade if meta.negate else 1.0 - shade
    out = np.full(shade.shape, -1, dtype=np.int16)
    if meta.mode == "raw":
        value = np.rint(shade * 255.0).astype(np.int16)
        out = np.where(value <= 100, value, -1).astype(np.int16)
        return out.astype(np.int8)
    out[occ > meta.occupied_thresh] = 100
    out[occ < meta.free_thresh] = 0
    if keep_saver_unknown and saver_grey_reads_free(meta):
        out[np.abs(shade * 255.0 - SAVER_UNKNOWN) < 1e-6] = -1
    if meta.mode == "scale":
        between = (occ >= meta.free_thresh) & (occ <= meta.occupied_thresh)
        span = meta.occupied_thresh - meta.free_thresh
        if span > 0:
            out[between] = np.rint(1 + 98 * (occ[between] - meta.free_thresh) / span).astype(np.int16)
        if alpha is not None:
            out[alpha < 1.0] = -1
    return out.astype(np.int8)


def _load_ros_map(path: Path) -> MapGeometry:
    meta = read_map_yaml(path)
    where = str(path)
    if not meta.image.is_file():
        raise MapError(f"{where}: image file {meta.image} not found")
    shade, alpha = read_map_image(meta.image)
    grid = occupancy(meta, shade, alpha)
    if saver_grey_reads_free(meta) and np.any(np.abs(shade * 255.0 - SAVER_UNKNOWN) < 1e-6):
        logging.getLogger("tmr").warning(
            "%s: free_thresh %g would read map_saver's unknown grey (%d) as free (a Nav2 map_saver default before "
            "navigation2 #5278); those cells are kept unknown, so they are obstacles",
            path,
            meta.free_thresh,
            SAVER_UNKNOWN,
        )
    res = meta.resolution
    ox, oy, yaw = meta.origin
    # only known free cells are planned in: occupied and unknown are obstacles (tmr's conservative reading); in raw
    # mode a cell is free when its occupancy (percent) is below free_thresh
    free = (grid >= 0) & (grid < meta.free_thresh * 100.0) if meta.mode == "raw" else grid == 0
    height, width = free.shape
    geom = _polygonise(~free, res, ox, oy)
    footprint = box(ox, oy, ox + width * res, oy + height * res)
    known = None
    if free.any():
        rows = np.nonzero(free.any(axis=1))[0]
        cols = np.nonzero(free.any(axis=0))[0]
        known_box = box(
            ox + cols[0] * res,
            oy + (height - rows[-1] - 1) * res,
            ox + (cols[-1] + 1) * res,
            oy + (height - rows[0]) * res,
        )
        if yaw != 0.0:
            known_box = shapely.affinity.rotate(known_box, yaw, origin=(ox, oy), use_radians=True)
        known = tuple(float(v) for v in known_box.bounds)
    if yaw != 0.0:
        geom = shapely.affinity.rotate(geom, yaw, origin=(ox, oy), use_radians=True)
        footprint = shapely.affinity.rotate(footprint, yaw, origin=(ox, oy), use_radians=True)
        rect = box(*footprint.bounds)
        geom = shapely.union(geom, rect.difference(footprint))
    return MapGeometry(geom, tuple(float(v) for v in footprint.bounds), known)  # type: ignore[arg-type]


def _polygonise(occupied: NDArray[np.bool_], res: float, ox: float, oy: float) -> BaseGeometry:
    """Union of boxes covering the occupied cells; image row 0 is the top (largest y)."""
    height, width = occupied.shape
    if not occupied.any():
        return shapely.GeometryCollection()
    padded = np.zeros((height, width + 2), dtype=np.int8)
    padded[:, 1:-1] = occupied
    diff = np.diff(padded, axis=1)
    rows_s, cols_s = np.nonzero(diff == 1)
    _, cols_e = np.nonzero(diff == -1)  # same row-major order as the starts
    # merge identical runs of consecutive rows into one rectangle
    rects: list[list[int]] = []  # [col_start, col_end, row_top, row_bottom]
    open_runs: dict[tuple[int, int], list[int]] = {}
    for r, c0, c1 in zip(rows_s.tolist(), cols_s.tolist(), cols_e.tolist(), strict=True):
        rect = open_runs.get((c0, c1))
        if rect is not None and rect[3] == r - 1:
            rect[3] = r
        else:
            rect = [c0, c1, r, r]
            rects.append(rect)
            open_runs[(c0, c1)] = rect
    arr = np.array(rects, dtype=float)
    x0 = ox + arr[:, 0] * res
    x1 = ox + arr[:, 1] * res
    y1 = oy + (height - arr[:, 2]) * res
    y0 = oy + (height - arr[:, 3] - 1) * res
    return shapely.union_all(shapely.box(x0, y0, x1, y1))


# ------------------------------------------------------------------------------------------------------------
# GeoJSON and WKT
# ------------------------------------------------------------------------------------------------------------
def _positive_property(props: dict[str, Any], key: str, what: str) -> float | None:
    if key not in props or props[key] is None:
        return None
    v = props[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
        raise MapError(f"{what}: property {key!r} must be a positive number of metres, got {v!r}")
    return float(v)


def _geojson_geometry(obj: Any, props: dict[str, Any], what: str) -> list[BaseGeometry]:
    if not isinstance(obj, dict) or "type" not in obj:
        raise MapError(f"{what}: expected a GeoJSON geometry object with a 'type', got {str(obj)[:60]!r}")
    kind = obj["type"]
    if kind == "GeometryCollection":
        out: list[BaseGeometry] = []
        for k, g in enumerate(obj.get("geometries") or []):
            out += _geojson_geometry(g, props, f"{what} geometry #{k}")
        return out
    if kind not in ("Point", "MultiPoint", "LineString", "MultiLineString", "Polygon", "MultiPolygon"):
        raise MapError(f"{what}: unsupported geometry type {kind!r}")
    try:
        geom = shapely.geometry.shape(obj)
    except Exception as exc:  # shapely raises various errors on bad coordinates
        raise MapError(f"{what}: malformed {kind} coordinates: {exc}") from None
    check_geometry(geom, what)
    if kind in ("Point", "MultiPoint"):
        radius = _positive_property(props, "radius", what)
        if radius is not None:
            geom = geom.buffer(radius, quad_segs=QUAD_SEGS)
    elif kind in ("LineString", "MultiLineString"):
        width = _positive_property(props, "width", what)
        if width is not None:
            geom = geom.buffer(width / 2.0, quad_segs=QUAD_SEGS, cap_style="flat", join_style="mitre")
    return [geom]


def _load_geojson(path: Path) -> MapGeometry:
    try:
        return _read_geojson(path)
    except RecursionError:  # [[[[... or GeometryCollections nested deeper than the parser's stack
        raise MapError(f"{path}: nested too deeply to be a map (GeoJSON expected)") from None


def _low_height(props: dict[str, Any], what: str) -> float | None:
    """The ``"height"`` property [m] of a low obstacle, None when absent; MapError unless a finite number > 0."""
    if "height" not in props or props["height"] is None:
        return None
    v = props["height"]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
        raise MapError(
            f"{what}: property 'height' (a low obstacle's height) must be a positive number of metres, got {v!r}"
        )
    return float(v)


def _read_geojson(path: Path) -> MapGeometry:
    from tmr.files import read_text

    try:
        doc = json.loads(read_text(path, "GeoJSON map", MapError, encoding="utf-8-sig"))
    except json.JSONDecodeError as exc:
        raise MapError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    if not isinstance(doc, dict) or "type" not in doc:
        raise MapError(f"{path}: not a GeoJSON object (a JSON object with a 'type' member expected)")
    bounds = None
    if "bounds" in doc:
        bounds = check_bounds(doc["bounds"], f"{path}: top-level 'bounds'")
    geoms: list[BaseGeometry] = []
    kind = doc["type"]
    if kind == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list):
            raise MapError(f"{path}: FeatureCollection without a 'features' list")
    elif kind == "Feature":
        features = [doc]
    else:
        return MapGeometry(_geojson_geometry(doc, {}, str(path)), bounds)
    lows: list[LowObstacle] = []
    for k, feat in enumerate(features):
        what = f"{path}: feature #{k}"
        if not isinstance(feat, dict) or feat.get("type") != "Feature":
            raise MapError(f"{what}: not a GeoJSON Feature")
        props = feat.get("properties") or {}
        if not isinstance(props, dict):
            raise MapError(f"{what}: 'properties' must be an object")
        if props.get("name"):
            what += f" ({props['name']})"
        height = _low_height(props, what)
        if feat.get("geometry") is None:
            continue  # GeoJSON allows unlocated features
        parts = _geojson_geometry(feat["geometry"], props, what)
        if height is None:
            geoms += parts
            continue
        footprint = _polygonal(shapely.union_all(parts))
        if footprint.is_empty or footprint.area <= 0.0:
            raise MapError(
                f"{what}: a low obstacle (property 'height') needs an area: a polygon, a point with a 'radius' or a "
                f"line with a 'width'"
            )
        name = props.get("name")
        lows.append(LowObstacle(str(name) if name else f"low obstacle {len(lows) + 1}", footprint, height))
    return MapGeometry(geoms, bounds, None, tuple(lows))


def _polygonal(geom: BaseGeometry) -> BaseGeometry:
    """The polygons of ``geom`` (a union may leave stray lines or points next to them)."""
    parts = [g for g in shapely.get_parts(geom) if isinstance(g, shapely.Polygon) and not g.is_empty]
    if not parts:
        return shapely.Polygon()
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


_WKT_BOUNDS = re.compile(r"^#\s*bounds\s*[:=]\s*(.*)$", re.IGNORECASE)


def _load_wkt(path: Path) -> tuple[list[BaseGeometry], Bounds | None]:
    from tmr.files import read_text

    text = read_text(path, "WKT map", MapError, encoding="utf-8-sig")
    bounds = None
    body: list[tuple[int, str]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        m = _WKT_BOUNDS.match(s)
        if m:
            numbers = m.group(1).replace(",", " ").replace("[", " ").replace("]", " ").split()
            bounds = check_bounds(numbers, f"{path}: line {lineno}")
        elif s and not s.startswith("#"):
            body.append((lineno, s))
    if not body:
        return [], bounds
    try:
        geoms = [shapely.from_wkt(" ".join(s for _, s in body))]
    except shapely.errors.GEOSException:
        geoms = []
        for lineno, s in body:  # one geometry per line: find the bad one
            try:
                geoms.append(shapely.from_wkt(s))
            except shapely.errors.GEOSException as exc:
                raise MapError(f"{path}: line {lineno}: not valid WKT ({exc}): {s[:60]!r}") from None
    for k, g in enumerate(geoms):
        check_geometry(g, f"{path}: geometry #{k}")
    return geoms, bounds
