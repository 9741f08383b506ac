"""Builds skinkit: the Python package and its C core `skinkit._core`, against CPython's stable ABI.

One abi3 wheel (Py_LIMITED_API 3.11) loads in every Blender from 4.2 on. Set SKINKIT_WERROR=1
(CI and `make test` do) to turn compiler warnings into errors.
"""
import os
import re
from glob import glob

from setuptools import Extension, find_packages, setup
from setuptools.command.bdist_wheel import bdist_wheel



def package_version() -> str:
    """skinkit.__version__, read from the file (importing the package would need the extension built)."""
    with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "skinkit", "__init__.py")) as stream:
        return re.search(r'^__version__ = "([^"]+)"$', stream.read(), re.M).group(1)


VERSION = package_version()

compile_args = ["-std=c11", "-O3", "-Wall", "-Wextra", "-pedantic", "-fvisibility=hidden", "-pthread"]
link_args = ["-pthread"]
if os.environ.get("SKINKIT_WERROR") == "1":
    compile_args.append("-Werror")
# SKINKIT_SANITIZE=1 builds the extension under AddressSanitizer and UndefinedBehaviorSanitizer, for `make
# fuzz-sanitized` (Python must then run with the sanitizer runtime preloaded).
if os.environ.get("SKINKIT_SANITIZE") == "1":
    sanitizers = ["-fsanitize=address,undefined", "-fno-sanitize-recover=undefined", "-fno-omit-frame-pointer"]
    compile_args += sanitizers + ["-O1", "-g"]
    link_args += sanitizers


class AbiThreeWheel(bdist_wheel):
    """Tags the wheel cp311-abi3 so pip and Blender accept it for every CPython >= 3.11."""

    def finalize_options(self):
        self.py_limited_api = "cp311"
        super().finalize_options()


# The core's C files, in csrc/ or any folder below it, with the generated binding among them
# (csrc/binding/pymodule.c, from scripts/gen_bindings.py).
core = Extension(
    "skinkit._core",
    sources=sorted(glob("csrc/**/*.c", recursive=True)),
    depends=sorted(glob("csrc/**/*.h", recursive=True)),
    include_dirs=["csrc", "csrc/common"],
    define_macros=[("Py_LIMITED_API", "0x030B0000")],
    py_limited_api=True,
    extra_compile_args=compile_args,
    extra_link_args=link_args,
    libraries=["lapacke", "lapack", "blas", "qhull_r"],
)

setup(
    name="skinkit",
    version=VERSION,
    description="Animation-space and linear-blend skinning for Blender, with a native C core",
    license="GPL-3.0-or-later",
    python_requires=">=3.11",
    packages=find_packages(include=["skinkit", "skinkit.*"]),
    package_data={"skinkit": ["_core.pyi"],  # the generated stubs, so editors and type checkers know _core
                  "skinkit.shaders": ["*.glsl"]},  # the runtime's GLSL shaders, read by skinkit.shaders.source
    install_requires=["numpy"],
    ext_modules=[core],
    cmdclass={"bdist_wheel": AbiThreeWheel},
    entry_points={"console_scripts": ["skinkit = skinkit.cli:main"]},
)
