"""Builds skinkit: the Python package and its C core `skinkit._core`, against CPython's stable ABI.

One abi3 wheel (Py_LIMITED_API 3.11) loads in every Blender from 4.2 on. Set SKINKIT_WERROR=1
(CI and `make test` do) to turn compiler warnings into errors.
"""
import os
from glob import glob

from setuptools import Extension, setup
from setuptools.command.bdist_wheel import bdist_wheel

VERSION = "0.1.0"

compile_args = ["-std=c11", "-O3", "-Wall", "-Wextra", "-pedantic", "-fvisibility=hidden", "-pthread"]
if os.environ.get("SKINKIT_WERROR") == "1":
    compile_args.append("-Werror")


class AbiThreeWheel(bdist_wheel):
    """Tags the wheel cp311-abi3 so pip and Blender accept it for every CPython >= 3.11."""

    def finalize_options(self):
        self.py_limited_api = "cp311"
        super().finalize_options()


core = Extension(
    "skinkit._core",
    sources=sorted(glob("csrc/*.c")) + sorted(glob("csrc/offline/lod/*.c")),
    depends=sorted(glob("csrc/*.h")) + sorted(glob("csrc/offline/lod/*.h")),
    include_dirs=["csrc", "csrc/offline/lod"],
    define_macros=[("Py_LIMITED_API", "0x030B0000")],
    py_limited_api=True,
    extra_compile_args=compile_args,
    extra_link_args=["-pthread"],
    libraries=["lapacke", "lapack", "blas"],
)

setup(
    name="skinkit",
    version=VERSION,
    description="Animation-space and linear-blend skinning for Blender, with a native C core",
    license="GPL-3.0-or-later",
    python_requires=">=3.11",
    packages=["skinkit", "skinkit.blender"],
    install_requires=["numpy"],
    ext_modules=[core],
    cmdclass={"bdist_wheel": AbiThreeWheel},
    entry_points={"console_scripts": ["skinkit = skinkit.cli:main"]},
)
