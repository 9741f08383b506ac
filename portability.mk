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
WINE := OPENBLAS_NUM_THREADS=1 WINEPREFIX=$(abspath $(WINDOWS_DIR))/wineprefix WINEDEBUG=-all WINEDLLOVERRIDES=mscoree,mshtml= $(firstword $(wildcard /usr/bin/wine64 /usr/lib/wine/wine64) wine64)
test-windows:
	$(MAKE) -j$(shell nproc) $(WINDOWS_TESTS)
	cp $(WINDOWS_OPENBLAS)/lib/libscipy_openblas.dll $(WINDOWS_DIR)/
	for program in $(WINDOWS_TESTS); do \
		$(WINE) $$program > /dev/null || { echo "$$program failed under Wine"; exit 1; }; \
	done
	@echo "windows (MinGW-w64, Wine): $(words $(WINDOWS_TESTS)) C test programs passed"

test-portability: check-clang test-windows

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
