"""The masks' rasterizer (the splat kernel's `ah_mesh_rasterize`) against its numpy
reference: the same faces and barycentrics bit for bit, on the built-in head and on triangle
soups with ties, clipped faces and faces behind the camera."""

import dataclasses

import numpy as np
import pytest

from archhead_addon.flame import load_model
from archhead_addon.flame.lbs import forward
from archhead_addon.sequences.demo import demo_sequence
from archhead_addon.splat.kernel import rasterize_mesh
from archhead_addon.splat.mesh_reference import rasterize as reference
from archhead_addon.train.parts_mask import rasterize

CODES = ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")


def assert_same(points, faces, K, w2c, size):
    face_at, bary = rasterize(points, faces, K, w2c, size)
    want_faces, want_bary = reference(points, faces, K, w2c, size)
    np.testing.assert_array_equal(face_at, want_faces)
    np.testing.assert_array_equal(bary, want_bary)
    return face_at


@pytest.mark.parametrize("size", [(512, 512), (97, 131)])
def test_the_head_matches_the_reference(size):
    model = load_model()
    seq = demo_sequence(4, image_size=size[::-1])
    turned = dataclasses.replace(seq, rotation=seq.rotation + np.array([0.0, 2.4, 0.3]))
    shifted = dataclasses.replace(seq, translation=seq.translation + np.array([0.12, -0.05, 0]))
    for s in (seq, turned, shifted):  # facing, from behind, half out of the frame
        for t in range(len(s.expr)):
            verts = forward(model, **{k: getattr(s, k)[t] for k in CODES})[0]
            found = assert_same(verts, model.faces, s.K[t], s.w2c[t], size)
            assert 0.01 < (found >= 0).mean() < 0.9


def test_ties_clipped_and_behind_the_camera_match_the_reference():
    rng = np.random.default_rng(7)
    K = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
    w2c = np.eye(4)
    points = rng.uniform([-1.5, -1.2, -0.5], [1.5, 1.2, 3.0], size=(300, 3))
    faces = rng.integers(0, len(points), size=(400, 3))
    faces = np.concatenate([faces, faces[:50], faces[:20, ::-1]])  # equal depths: ties
    points[:10, 2] = 5e-5  # inside the near plane: their faces are left out
    found = assert_same(points, faces, K, w2c, (48, 64))
    assert (found >= 0).any() and not (found >= 400).any()  # a copy never beats its twin


def test_a_face_outside_the_vertices_is_refused():
    with pytest.raises(ValueError, match="out of range"):
        rasterize_mesh(np.zeros((3, 2)), np.ones(3), np.array([[0, 1, 3]]), (4, 4))
