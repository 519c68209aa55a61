"""The zip from `make extension`, installed with Blender's command line into a clean profile,
is enabled in a real window with its panel (the session fixture does the install)."""

import json

import pytest

pytestmark = pytest.mark.ui


def test_install_and_enable(blender_session):
    from ui_session import OUT

    result = json.loads((OUT / "install" / "result.json").read_text())
    assert result["status"] == "passed"
    assert "bl_ext.user_default.archhead" in result["data"]["addons"]
    assert (OUT / "install" / result["shots"][0]).stat().st_size > 10_000
