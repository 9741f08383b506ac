"""The extension zip's manifest lists exactly the platforms of the wheel inside it (scripts/build_extension.py reads
them from the wheel's platform tag): Linux, Windows and macOS tags, several tags in one name, and a tag Blender has
no platform for refused."""
import os
import sys

import pytest

from tests.conftest import ROOT

sys.path.insert(0, os.path.join(ROOT, "scripts"))
from build_extension import wheel_platforms  # noqa: E402


@pytest.mark.parametrize("tag, platforms", [
    ("manylinux_2_34_x86_64", ["linux-x64"]),
    ("manylinux_2_17_x86_64.manylinux2014_x86_64", ["linux-x64"]),
    ("manylinux_2_28_aarch64", ["linux-arm64"]),
    ("win_amd64", ["windows-x64"]),
    ("macosx_11_0_arm64", ["macos-arm64"]),
    ("macosx_10_13_x86_64", ["macos-x64"]),
    ("macosx_11_0_universal2", ["macos-arm64", "macos-x64"]),
])
def test_a_wheel_tag_names_its_blender_platforms(tag, platforms):
    assert wheel_platforms(f"dist/skinkit-0.1.0-cp311-abi3-{tag}.whl") == platforms


def test_a_tag_without_a_blender_platform_is_refused():
    with pytest.raises(SystemExit, match="no Blender platform"):
        wheel_platforms("dist/skinkit-0.1.0-cp311-abi3-win32.whl")
    with pytest.raises(SystemExit, match="no Blender platform"):
        wheel_platforms("dist/skinkit-0.1.0-py3-none-any.whl")
