"""Shared fixtures: the sample scenes, opened in Blender's Python module (real Blender, headless)."""
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "blend_samples")
SAMPLE_NAMES = ("arm", "creature")


def sample_path(name: str) -> str:
    return os.path.join(SAMPLES, f"{name}.blend")


@pytest.fixture
def open_sample():
    """open_sample(name) loads blend_samples/NAME.blend and returns its skinned mesh object."""
    import bpy

    from skinkit.blender.scene import find_skinned_mesh

    def load(name):
        bpy.ops.wm.open_mainfile(filepath=sample_path(name), load_ui=False)
        return find_skinned_mesh(bpy.context.scene.objects)

    return load


@pytest.fixture(scope="session")
def addon():
    """The add-on registered in this process, as Blender registers it."""
    import addon as skinkit_addon

    skinkit_addon.register()
    yield skinkit_addon
    skinkit_addon.unregister()
