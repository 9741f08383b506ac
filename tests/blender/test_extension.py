"""The Blender extension zip (`make extension`) installs into headless Blender with Blender's own
extension API, brings its own copy of skinkit (the bundled abi3 wheel), and its operators run."""
import glob
import json
import os
import subprocess
import sys
import sysconfig

from tests.conftest import ROOT, sample_path

INSTALL_AND_RUN = """
import json, sys
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
result = bpy.ops.extensions.package_install_files(filepath=sys.argv[-2], repo="user_default",
                                                   enable_on_install=True)
import skinkit
bpy.ops.wm.open_mainfile(filepath=sys.argv[-1], load_ui=False)
bpy.context.view_layer.objects.active = bpy.data.objects["arm"]
converted = bpy.ops.skinkit.convert_to_animation_space()
compared = bpy.ops.skinkit.compare_with_armature()
print("RESULT " + json.dumps({"install": sorted(result), "skinkit": skinkit.__file__,
                              "converted": sorted(converted), "compared": sorted(compared),
                              "has_model": "skinkit_model" in bpy.data.objects["arm"].data}))
from skinkit.blender import compat
compat.exit_process(0)  # bpy 4.2's teardown can crash once the work is done
"""


def test_extension_zip_installs_and_runs(tmp_path):
    zips = glob.glob(os.path.join(ROOT, "dist", "skinkit-*.zip"))
    assert len(zips) == 1, "build the extension first: make extension"
    # -S keeps this venv's site hooks (and its editable skinkit) away: bpy and numpy come from PYTHONPATH,
    # skinkit must come from the extension.
    environment = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender_user"),
                       PYTHONPATH=sysconfig.get_paths()["purelib"])
    script = tmp_path / "install_and_run.py"
    script.write_text(INSTALL_AND_RUN)
    completed = subprocess.run([sys.executable, "-S", str(script), zips[0], sample_path("arm")], cwd=tmp_path,
                               env=environment, capture_output=True, text=True, timeout=300)
    lines = [line for line in completed.stdout.splitlines() if line.startswith("RESULT ")]
    assert completed.returncode == 0 and lines, completed.stdout + completed.stderr
    result = json.loads(lines[0][len("RESULT "):])
    assert result["install"] == ["FINISHED"]
    assert result["skinkit"].startswith(str(tmp_path / "blender_user" / "extensions"))
    assert result["converted"] == ["FINISHED"] and result["compared"] == ["FINISHED"] and result["has_model"]
