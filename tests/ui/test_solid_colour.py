"""Solid mode shows the avatar's colour (tests/ui/blender/solid_colour.py)."""

import pytest

pytestmark = pytest.mark.ui


def test_solid_mode_shows_the_avatars_colour(blender_session, ui_data):
    from coloured_avatar import write_coloured_avatar
    from ui_session import OUT

    out = OUT / "solid_colour"
    avatar = write_coloured_avatar(ui_data["avatar"], ui_data["folder"] / "skin_avatar.npz")
    result = blender_session.ui("solid_colour.py", out, str(ui_data["sequence"]), str(avatar))
    r, g, b = result["data"]["solid_avatar"]["median_rgb"]
    assert r > g > b
