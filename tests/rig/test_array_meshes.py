"""Quads and boxes are built as arrays (render.scene.TriangleMesh), not trimesh meshes (start-up
cost, issue 16): they must be the meshes trimesh built before, attribute for attribute the
renderers and the effect inference read."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rig.build import box_mesh, quad_mesh


@pytest.mark.parametrize("size, center", [([1.0, 2.0, 3.0], [0.5, -1.0, 2.0]), ([0.3, 0.3, 0.7], [10.0, 0.0, 0.0])])
def test_box_is_trimeshs_box(size, center):
    ours, theirs = box_mesh(size, center), trimesh.creation.box(extents=size)
    theirs.apply_translation(center)
    assert np.array_equal(ours.vertices, theirs.vertices) and np.array_equal(ours.faces, theirs.faces)
    assert np.allclose(ours.face_normals, theirs.face_normals) and np.allclose(ours.area_faces, theirs.area_faces)
    assert np.array_equal(ours.bounds, theirs.bounds)
    assert ours.is_convex == theirs.is_convex is True and ours.visual.uv is None


def test_quad_is_trimeshs_quad():
    corners = np.array([[0.0, 0, 0], [2, 0, 0], [2, 1, 0.5], [0, 1, 0.5]])
    ours = quad_mesh(corners)
    theirs = trimesh.Trimesh(corners, [[0, 1, 2], [0, 2, 3]], process=False)
    assert np.array_equal(ours.vertices, theirs.vertices) and np.array_equal(ours.faces, theirs.faces)
    assert np.allclose(ours.face_normals, theirs.face_normals) and np.allclose(ours.area_faces, theirs.area_faces)
    assert ours.is_convex == theirs.is_convex is False  # open: trimesh's answer, read by render.effects
    assert np.array_equal(ours.visual.uv, [[0, 0], [1, 0], [1, 1], [0, 1]])
