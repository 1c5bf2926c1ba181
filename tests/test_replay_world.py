"""Obstacles become convex prisms that cover exactly the plan's polygons."""

from __future__ import annotations

import os

import pytest
import shapely
from shapely.geometry import Point, Polygon

from tmr.replay.world import OBSTACLE_HEIGHT, convex_pieces, world_xml


def test_convex_polygon_is_one_piece() -> None:
    disc = Point(3.0, 4.0).buffer(0.5, quad_segs=16)
    (piece,) = convex_pieces([disc])
    assert Polygon(piece).equals_exact(shapely.normalize(disc), 1e-12) or Polygon(piece).area == pytest.approx(
        disc.area, rel=1e-12
    )


def test_concave_polygon_and_holes_are_covered_by_convex_pieces() -> None:
    ell = Polygon([(0, 0), (4, 0), (4, 1), (1, 1), (1, 3), (0, 3)])
    ring = Point(8, 8).buffer(2.0, quad_segs=8).difference(Point(8, 8).buffer(1.0, quad_segs=8))
    for poly in (ell, ring):
        pieces = [Polygon(p) for p in convex_pieces([poly])]
        assert len(pieces) > 1
        for p in pieces:
            assert p.area == pytest.approx(p.convex_hull.area, rel=1e-9)  # convex
        union = shapely.union_all(pieces)
        assert union.symmetric_difference(poly).area == pytest.approx(0.0, abs=1e-9)


def test_world_compiles_in_mujoco() -> None:
    os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo's first import (offscreen rendering, test_replay_chain)
    mujoco = pytest.importorskip("mujoco")
    ell = Polygon([(2, 2), (6, 2), (6, 3), (3, 3), (3, 5), (2, 5)])
    assets, body, names = world_xml([ell], (0.0, 0.0, 10.0, 8.0))
    model = mujoco.MjModel.from_xml_string(f"<mujoco><asset>{assets}</asset><worldbody>{body}</worldbody></mujoco>")
    assert len(names) == 4 + len(convex_pieces([ell]))  # four walls + the pieces
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    pts = []
    for k in range(model.ngeom):
        if model.geom_type[k] == mujoco.mjtGeom.mjGEOM_MESH:
            m = model.geom_dataid[k]
            v = model.mesh_vert[model.mesh_vertadr[m] : model.mesh_vertadr[m] + model.mesh_vertnum[m]]
            pts.append(data.geom_xpos[k] + v @ data.geom_xmat[k].reshape(3, 3).T)
    import numpy as np

    pts = np.vstack(pts)
    assert pts[:, 2].min() == pytest.approx(0.0, abs=1e-6)  # MuJoCo stores mesh vertices in float32
    assert pts[:, 2].max() == pytest.approx(OBSTACLE_HEIGHT, abs=1e-6)
    hull = shapely.MultiPoint(pts[:, :2]).convex_hull
    assert ell.difference(hull).area == pytest.approx(0.0, abs=1e-6)  # the prisms cover the polygon
