"""The version is written once, in skinkit/__init__.py; the C header's SK_VERSION_* must agree with it."""
import os
import re

import skinkit
from tests.conftest import ROOT


def test_the_c_header_has_the_package_version():
    with open(os.path.join(ROOT, "csrc", "skinkit.h")) as stream:
        header = stream.read()
    parts = [re.search(rf"^#define SK_VERSION_{part} (\d+)$", header, re.M) for part in ("MAJOR", "MINOR", "PATCH")]
    assert all(parts), "csrc/skinkit.h must define SK_VERSION_MAJOR, _MINOR and _PATCH"
    assert ".".join(p.group(1) for p in parts) == skinkit.__version__


def test_the_manifest_leaves_the_version_to_the_build():
    """scripts/build_extension.py writes skinkit.__version__ into the staged manifest; the checked-in one keeps a
    placeholder, so there is no second copy to forget."""
    with open(os.path.join(ROOT, "addon", "blender_manifest.toml")) as stream:
        assert re.search(r'^version = "0\.0\.0"$', stream.read(), re.M)
