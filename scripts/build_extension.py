"""Builds the Blender extension zip: addon/ plus the skinkit wheel, with Blender's own `extension build`.

Usage: python scripts/build_extension.py WHEEL OUTPUT_DIR
Blender's command is `blender --command extension build`; the bpy module ships the same implementation
as a standalone script (addons_core/bl_pkg/cli/blender_ext.py), which this runs, followed by its
`validate` on the result. The manifest's platforms are the wheel's, read from its platform tag, so the zip lists
exactly the platforms whose wheel it holds. skinkit's pure-Python dependencies that Blender does not bundle
(BUNDLED) travel as their own wheels, at the versions installed here (requirements-dev.txt's pins), downloaded once
into build/extension-wheels.
"""
import os
import re
import shutil
import subprocess
import sys
import tempfile
from importlib.metadata import version

import bpy

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def blender_ext_script() -> str:
    scripts = bpy.utils.system_resource("SCRIPTS")
    path = os.path.join(scripts, "addons_core", "bl_pkg", "cli", "blender_ext.py")
    if not os.path.isfile(path):
        sys.exit(f"Blender's extension builder is missing: {path}")
    return path


def package_version() -> str:
    """skinkit.__version__, read from skinkit/__init__.py, the one place it is written."""
    with open(os.path.join(ROOT, "skinkit", "__init__.py")) as stream:
        return re.search(r'^__version__ = "([^"]+)"$', stream.read(), re.M).group(1)


def filled_in(manifest: str, key: str, line: str) -> str:
    manifest, replaced = re.subn(rf"^{key} = .*$", line, manifest, flags=re.M)
    if replaced != 1:
        sys.exit(f"addon/blender_manifest.toml must have one `{key} = ...` line")
    return manifest


# Blender's platform names for the wheel platform tags skinkit builds (PEP 425; macOS tags carry a version).
WHEEL_PLATFORMS = [(re.compile(r"^(many|musl)?linux(_\d+_\d+)?_x86_64$"), "linux-x64"),
                   (re.compile(r"^(many|musl)?linux(_\d+_\d+)?_aarch64$"), "linux-arm64"),
                   (re.compile(r"^win_amd64$"), "windows-x64"),
                   (re.compile(r"^win_arm64$"), "windows-arm64"),
                   (re.compile(r"^macosx_\d+_\d+_(x86_64|universal2)$"), "macos-x64"),
                   (re.compile(r"^macosx_\d+_\d+_(arm64|universal2)$"), "macos-arm64")]


def wheel_platforms(wheel: str) -> list[str]:
    """Blender's names of the platforms a wheel's file name says it runs on (its tag may list several)."""
    tags = os.path.basename(wheel)[:-len(".whl")].split("-")[-1].split(".")
    platforms = sorted({name for tag in tags for pattern, name in WHEEL_PLATFORMS if pattern.match(tag)})
    if not platforms:
        sys.exit(f"{wheel}: no Blender platform for its platform tag {'.'.join(tags)}")
    return platforms


#: skinkit's runtime dependencies beside numpy (which Blender bundles): pure Python, one wheel for every platform.
BUNDLED = ("threadpoolctl",)
DEPENDENCY_WHEELS = os.path.join(ROOT, "build", "extension-wheels")


def dependency_wheels() -> list[str]:
    """The BUNDLED wheels at the installed versions, from DEPENDENCY_WHEELS (pip downloads what is missing)."""
    paths = []
    for name in BUNDLED:
        pinned = f"{name}=={version(name)}"
        found = [f for f in os.listdir(DEPENDENCY_WHEELS) if f.startswith(f"{name}-{version(name)}-")] \
            if os.path.isdir(DEPENDENCY_WHEELS) else []
        if not found:
            subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
                            pinned, "-d", DEPENDENCY_WHEELS], check=True)
            found = [f for f in os.listdir(DEPENDENCY_WHEELS) if f.startswith(f"{name}-{version(name)}-")]
        if len(found) != 1 or not found[0].endswith("-py3-none-any.whl"):
            sys.exit(f"{pinned}: expected one pure-Python wheel in {DEPENDENCY_WHEELS}, found {found}")
        paths.append(os.path.join(DEPENDENCY_WHEELS, found[0]))
    return paths


def stage(wheel: str, staging: str) -> None:
    """addon/ with the wheel and its dependencies' under ./wheels/ and the manifest naming them and skinkit's
    version."""
    shutil.copytree(os.path.join(ROOT, "addon"), staging, ignore=shutil.ignore_patterns("__pycache__"))
    os.makedirs(os.path.join(staging, "wheels"))
    wheels = [wheel, *dependency_wheels()]
    for path in wheels:
        shutil.copy2(path, os.path.join(staging, "wheels"))
    shutil.copy2(os.path.join(ROOT, "LICENSE"), staging)
    manifest_path = os.path.join(staging, "blender_manifest.toml")
    with open(manifest_path) as stream:
        manifest = stream.read()
    listed = ", ".join(f'"./wheels/{os.path.basename(path)}"' for path in wheels)
    manifest = filled_in(manifest, "wheels", f"wheels = [{listed}]")
    manifest = filled_in(manifest, "version", f'version = "{package_version()}"')
    platforms = ", ".join(f'"{name}"' for name in wheel_platforms(wheel))
    manifest = filled_in(manifest, "platforms", f"platforms = [{platforms}]")
    with open(manifest_path, "w") as stream:
        stream.write(manifest)


def main() -> None:
    wheel, output_dir = sys.argv[1], os.path.abspath(sys.argv[2])
    os.makedirs(output_dir, exist_ok=True)
    builder = blender_ext_script()
    with tempfile.TemporaryDirectory() as temporary:
        staging = os.path.join(temporary, "skinkit")
        stage(os.path.abspath(wheel), staging)
        subprocess.run([sys.executable, builder, "build", "--source-dir", staging, "--output-dir", output_dir],
                       check=True)
    built = [f for f in os.listdir(output_dir) if f.startswith("skinkit-") and f.endswith(".zip")]
    for name in built:
        subprocess.run([sys.executable, builder, "validate", os.path.join(output_dir, name)], check=True)
    print("\n".join(os.path.join(output_dir, name) for name in built))


if __name__ == "__main__":
    main()
