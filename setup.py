"""Builds skinkit: the Python package and its C core `skinkit._core`, against CPython's stable ABI.

One abi3 wheel (Py_LIMITED_API 3.11) loads in every Blender from 4.2 on. Set SKINKIT_WERROR=1
(CI and `make test` do) to turn compiler warnings into errors.
"""
import os
import re
import sys
from glob import glob
from pathlib import Path

from setuptools import Extension, find_packages, setup
from setuptools.command.bdist_wheel import bdist_wheel
from setuptools.command.build_clib import build_clib
from setuptools.command.build_ext import build_ext

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # scripts/portable_deps.py


def package_version() -> str:
    """skinkit.__version__, read from the file (importing the package would need the extension built)."""
    with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "skinkit", "__init__.py")) as stream:
        return re.search(r'^__version__ = "([^"]+)"$', stream.read(), re.M).group(1)


VERSION = package_version()

compile_args = ["-std=c11", "-O3", "-Wall", "-Wextra", "-pedantic", "-fvisibility=hidden", "-pthread"]
link_args = ["-pthread"]
# Windows: the GNU C11 core is built by MinGW-w64 GCC (AbiThreeBuild below), with C99 printf and Win32 threads.
if sys.platform == "win32":
    compile_args = [arg for arg in compile_args if arg != "-pthread"] + ["-D__USE_MINGW_ANSI_STDIO=1"]
    link_args = ["-static-libgcc"]
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


sources = sorted(glob("csrc/**/*.c", recursive=True))
include_dirs = ["csrc", "csrc/common"]
library_dirs: list[str] = []
libraries = ["lapacke", "lapack", "blas", "qhull_r"]  # Debian's (make deps)
# SKINKIT_LAPACK=scipy-openblas32 links the LAPACK PyPI's scipy-openblas32 ships for every platform (the wheels
# pyproject.toml's cibuildwheel section builds); a generated, force-included header maps the core's LAPACKE calls
# onto its scipy_-prefixed symbols (scripts/portable_deps.py).
if os.environ.get("SKINKIT_LAPACK") == "scipy-openblas32":
    import scipy_openblas32
    from scripts.portable_deps import write_prefix_header
    prefix_header = os.path.abspath(os.path.join("build", "sk_scipy_openblas.h"))
    write_prefix_header(Path(prefix_header), Path(scipy_openblas32.get_include_dir()) / "lapacke.h")
    include_dirs.append(scipy_openblas32.get_include_dir())
    library_dirs.append(scipy_openblas32.get_lib_dir())
    libraries = [scipy_openblas32.get_library()] + libraries[3:]
    compile_args += ["-include", prefix_header]
# SKINKIT_QHULL_SOURCE=DIR compiles reentrant Qhull from DIR/libqhull_r (scripts/portable_deps.py qhull DIR) into
# the extension, for platforms without a system Qhull.
# It is a static library of its own (built first by build_clib), compiled with Qhull's flags rather than ours.
static_libraries = []
if os.environ.get("SKINKIT_QHULL_SOURCE"):
    qhull_root = os.environ["SKINKIT_QHULL_SOURCE"]
    static_libraries.append(("skinkit_qhull_r", {"sources": sorted(glob(os.path.join(qhull_root, "libqhull_r", "*.c"))),
                                         "cflags": ["-O2", "-w"]}))
    include_dirs.append(qhull_root)
    libraries.remove("qhull_r")

# The core's C files, in csrc/ or any folder below it, with the generated binding among them
# (csrc/binding/pymodule.c, from scripts/gen_bindings.py).
core = Extension(
    "skinkit._core",
    sources=sources,
    depends=sorted(glob("csrc/**/*.h", recursive=True)),
    include_dirs=include_dirs,
    define_macros=[("Py_LIMITED_API", "0x030B0000")],
    py_limited_api=True,
    extra_compile_args=compile_args,
    extra_link_args=link_args,
    library_dirs=library_dirs,
    libraries=libraries,
)

class MinGWOnWindows:
    """Picks MinGW-w64 GCC instead of MSVC on Windows, for the core's C library and extension alike."""

    def initialize_options(self):
        super().initialize_options()
        if sys.platform == "win32":
            self.compiler = "mingw32"


class CoreLibraries(MinGWOnWindows, build_clib):
    pass


class CoreExtension(MinGWOnWindows, build_ext):
    pass


# SKINKIT_WITHOUT_EXTENSION=1 builds the package without its C extension: the Python files and metadata the
# cross-built Windows wheel is assembled from (scripts/windows_wheel.py), so this file stays their one source.
ext_modules = [] if os.environ.get("SKINKIT_WITHOUT_EXTENSION") == "1" else [core]

setup(
    name="skinkit",
    version=VERSION,
    description="Animation-space and linear-blend skinning for Blender, with a native C core",
    license="GPL-3.0-or-later",
    python_requires=">=3.11",
    packages=find_packages(include=["skinkit", "skinkit.*"]),
    package_data={"skinkit": ["_core.pyi"],  # the generated stubs, so editors and type checkers know _core
                  "skinkit.shaders": ["*.glsl"]},  # the runtime's GLSL shaders, read by skinkit.shaders.source
    install_requires=["numpy", "threadpoolctl"],  # threadpoolctl: skinkit/_blas.py
    ext_modules=ext_modules,
    libraries=static_libraries,
    cmdclass={"bdist_wheel": AbiThreeWheel, "build_clib": CoreLibraries, "build_ext": CoreExtension},
    entry_points={"console_scripts": ["skinkit = skinkit.cli:main"]},
)
