"""Builds skinkit: the Python package and its C core `skinkit._core`, against CPython's stable ABI.

One abi3 wheel (Py_LIMITED_API 3.11) loads in every Blender from 4.2 on. Set SKINKIT_WERROR=1
(CI and `make test` do) to turn compiler warnings into errors.
"""
import os
import re
from glob import glob

from setuptools import Extension, setup
from setuptools.command.bdist_wheel import bdist_wheel



def package_version() -> str:
    """skinkit.__version__, read from the file (importing the package would need the extension built)."""
    with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "skinkit", "__init__.py")) as stream:
        return re.search(r'^__version__ = "([^"]+)"$', stream.read(), re.M).group(1)


VERSION = package_version()

compile_args = ["-std=c11", "-O3", "-Wall", "-Wextra", "-pedantic", "-fvisibility=hidden", "-pthread"]
if os.environ.get("SKINKIT_WERROR") == "1":
    compile_args.append("-Werror")


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
    extra_link_args=["-pthread"],
    libraries=["lapacke", "lapack", "blas"],
)

setup(
    name="skinkit",
    version=VERSION,
    description="Animation-space and linear-blend skinning for Blender, with a native C core",
    license="GPL-3.0-or-later",
    python_requires=">=3.11",
    packages=["skinkit", "skinkit.blender", "skinkit.cli", "skinkit.cli.commands", "skinkit.lod"],
    install_requires=["numpy"],
    ext_modules=[core],
    cmdclass={"bdist_wheel": AbiThreeWheel},
    entry_points={"console_scripts": ["skinkit = skinkit.cli:main"]},
)
