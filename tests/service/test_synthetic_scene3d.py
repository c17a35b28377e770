"""The 3-D scenes' renderer: cast in bands of rows, the same pixels as in one piece."""

from __future__ import annotations

import numpy as np
import pytest

from service.synthetic import scene3d
from service.synthetic.scene3d import SCENE_KINDS, make_scene_3d


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_bands_of_rows_render_the_scene_of_one_piece(kind, monkeypatch):
    # A small camera (a band boundary every 7 rows, the last band short) sees the whole
    # layout; the noise is drawn band after band from the scene's generator.
    size = {"width": 230, "height": 173, "focal": 250.0}
    monkeypatch.setattr(scene3d, "RENDER_BAND_ROWS", 10_000)
    whole = make_scene_3d(kind, seed=3, lighting="side", **size)
    monkeypatch.setattr(scene3d, "RENDER_BAND_ROWS", 7)
    banded = make_scene_3d(kind, seed=3, lighting="side", **size)
    assert (banded.labels >= 0).any(), "the cables are in view"
    np.testing.assert_array_equal(banded.image, whole.image)
    np.testing.assert_array_equal(banded.depth_m, whole.depth_m)
    np.testing.assert_array_equal(banded.labels, whole.labels)
