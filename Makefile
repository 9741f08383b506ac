# skinkit: `make test` and `make demo` set up everything on a fresh Debian machine (apt + a pinned venv).
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
VERSION := $(shell sed -n 's/^__version__ = "\(.*\)"$$/\1/p' skinkit/__init__.py)
# The C core: every .c under csrc/ but the generated Python binding (csrc/binding/).
CORE_SOURCES := $(sort $(filter-out csrc/binding/%,$(shell find csrc -name '*.c')))
CORE_HEADERS := $(sort $(shell find csrc -name '*.h'))
# What a game engine embeds: evaluation and what it needs, linked without LAPACK (checked by test-core).
RUNTIME_SOURCES := $(sort $(wildcard csrc/common/*.c csrc/runtime/*.c))
CORE_INCLUDES := -Icsrc -Icsrc/common
CORE := skinkit/_core.abi3.so
WHEEL_RAW_DIR := dist/raw
EXTENSION := dist/skinkit-$(VERSION).zip

# Build tools, LAPACK, and the X11/GL client libraries that Blender's bpy module loads even headless.
# Mesa's EGL and llvmpipe (libegl-mesa0, libgl1-mesa-dri, libgbm1) give tests/gpu a headless OpenGL 4.3 context.
APT_PACKAGES := gcc make patchelf unzip liblapacke-dev libopenblas-dev \
	libx11-6 libxrender1 libxi6 libxxf86vm1 libxfixes3 libxkbcommon0 libsm6 libice6 \
	libgl1 libegl1 libglu1-mesa \
	libegl-mesa0 libgl1-mesa-dri libgbm1 \
	libqhull-dev

.PHONY: all deps venv build bindings test test-core test-python fuzz fuzz-sanitized demo wheel extension bench samples clean

all: build

deps: .stamp-apt
.stamp-apt:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing: $$missing"; \
		$(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi
	touch $@

venv: $(VENV)/.stamp
$(VENV)/.stamp: requirements-dev.txt | .stamp-apt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements-dev.txt
	touch $@

build: $(CORE)
# An editable install: the extension is built in place and the `skinkit` command lands in the venv.
$(CORE): $(shell find csrc -name '*.[ch]') setup.py $(VENV)/.stamp
	SKINKIT_WERROR=1 $(PY) -m pip install -q --no-deps --no-build-isolation -e .

# csrc/binding/pymodule.c and skinkit/_core.pyi from the spec; both are checked in (tests/binding/test_binding.py checks them).
bindings:
	$(PY) scripts/gen_bindings.py

# The C core's own tests, under AddressSanitizer and UndefinedBehaviorSanitizer.
SANITIZED_TESTS := build/test_core_sanitized build/test_fit_sanitized build/test_fit_errors_sanitized \
	build/test_metrics_sanitized build/test_metric_bounds_sanitized \
	build/test_lsqr_sanitized build/test_decompose_sanitized build/test_segment_sanitized \
	build/test_flatten_sanitized build/test_pack_sanitized \
	build/test_common_sanitized build/test_mesh_sanitized build/test_runtime_link_sanitized build/test_lod_sanitized \
	build/test_lod_chain_sanitized \
	build/test_runtime_sanitized build/test_skeleton_sanitized build/test_dqs_sanitized build/test_handles_sanitized \
	build/test_bake_sanitized
SANITIZE := -std=c11 -g -O1 -Wall -Wextra -Werror -fsanitize=address,undefined -fno-sanitize-recover=all \
	-fno-omit-frame-pointer
# Each core source is compiled once into a sanitized object (not once per test program), and the programs link them.
SANITIZED_OBJECTS_DIR := build/asan-objects
CORE_OBJECTS := $(patsubst csrc/%.c,$(SANITIZED_OBJECTS_DIR)/%.o,$(CORE_SOURCES))
RUNTIME_OBJECTS := $(patsubst csrc/%.c,$(SANITIZED_OBJECTS_DIR)/%.o,$(RUNTIME_SOURCES))
$(SANITIZED_OBJECTS_DIR)/%.o: csrc/%.c $(CORE_HEADERS) | .stamp-apt
	mkdir -p $(dir $@)
	gcc $(SANITIZE) $(CORE_INCLUDES) -c $< -o $@
build/test_%_sanitized: tests/c/test_%.c tests/c/test_support.c tests/c/test_support.h $(CORE_OBJECTS) \
		$(CORE_HEADERS) | .stamp-apt
	gcc $(SANITIZE) $(CORE_INCLUDES) $(CORE_OBJECTS) tests/c/test_support.c $(TEST_CASES) $< -llapacke -llapack -lblas -lqhull_r -lm -pthread -o $@

# A family split into two programs shares its fixtures: TEST_CASES is linked into both.
build/test_fit_sanitized build/test_fit_errors_sanitized: TEST_CASES := tests/c/fit_cases.c
build/test_fit_sanitized build/test_fit_errors_sanitized: tests/c/fit_cases.c tests/c/fit_cases.h
build/test_metrics_sanitized build/test_metric_bounds_sanitized: TEST_CASES := tests/c/metrics_cases.c
build/test_metrics_sanitized build/test_metric_bounds_sanitized: tests/c/metrics_cases.c tests/c/metrics_cases.h

# The runtime's claim to need no LAPACK, checked by linking common/ + runtime/ without it: the link test, the
# runtime family's own test, and dual-quaternion skinning with the handle rig's prediction (runtime code too).
RUNTIME_TESTS := build/test_runtime_link_sanitized build/test_runtime_sanitized build/test_dqs_sanitized
$(RUNTIME_TESTS): build/test_%_sanitized: tests/c/test_%.c tests/c/test_support.c tests/c/test_support.h \
		$(RUNTIME_OBJECTS) $(CORE_HEADERS) | .stamp-apt
	gcc $(SANITIZE) $(CORE_INCLUDES) $(RUNTIME_OBJECTS) tests/c/test_support.c $< -lm -pthread -o $@

test-core:
	$(MAKE) -j$(shell nproc) $(SANITIZED_TESTS)
	for program in $(SANITIZED_TESTS); do \
		ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 $$program || exit 1; \
	done

test-python: build $(EXTENSION)
	$(PY) -m pytest -q tests

test: test-core test-python

# The Blender-facing tests (tests/blender, tests/cli: the extension zip, the operators, the CLI) under the newest bpy
# of each Blender series from 4.2 on, each in its own venv cached by requirement hash (tests/matrix/blender_matrix.py).
.PHONY: test-blender-matrix
test-blender-matrix: build $(EXTENSION)
	nice $(PY) tests/matrix/blender_matrix.py

# Hostile calls to every skinkit._core entry point (tests/fuzz/binding_fuzz.py) and to every public function and
# method of the numpy API (tests/fuzz/api_fuzz.py, where each must answer with a result or a SkinkitError), in
# batches forked from a parent that has imported skinkit: no call may kill the process or hang. Each entry point's
# calls, refusals, raw exceptions, crashes and hangs go to FUZZ_RESULTS (and its table to FUZZ_RESULTS_MD); the
# passes resume from what it records, so on a shared machine `make fuzz` can be run in pieces (stop it, run it
# again) until every entry point has FUZZ_CALLS. `make test` runs a short seeded pass of both harnesses.
# Then a coverage-guided pass (atheris) over the OBJ/PC2 readers, frame lists and the CLI's arguments and files.
FUZZ_CALLS ?= 100000
FUZZ_API_CALLS ?= $(FUZZ_CALLS)
FUZZ_FILE_RUNS ?= 200000
FUZZ_RESULTS ?= bench/fuzz_results.json
FUZZ_RESULTS_MD ?= $(FUZZ_RESULTS:.json=.md)
fuzz: build
	$(PY) -m pip install -q -r requirements-fuzz.txt
	nice -n 15 $(PY) -m tests.fuzz.binding_fuzz --calls $(FUZZ_CALLS) --results $(FUZZ_RESULTS) --resume; \
		binding=$$?; \
		nice -n 15 $(PY) -m tests.fuzz.api_fuzz --calls $(FUZZ_API_CALLS) --results $(FUZZ_RESULTS) --resume; \
		api=$$?; \
		$(PY) -m tests.fuzz.results $(FUZZ_RESULTS) > $(FUZZ_RESULTS_MD); \
		[ $$binding = 0 ] && [ $$api = 0 ]
	mkdir -p build/fuzz/corpus
	$(PY) -m tests.fuzz.fuzz_files -runs=$(FUZZ_FILE_RUNS) -max_total_time=1200 -artifact_prefix=build/fuzz/ \
		build/fuzz/corpus

# The binding fuzz pass and a seeded public-API pass once more against a sanitizer build of the extension, made in a
# scratch copy of the tree (build/sanitized) so the normal build stays as it is: heap overflows and undefined
# behaviour that do not crash abort there with a report. The sanitizers write their reports into one folder
# (log_path); the target fails on a crash, a hang or any report there (tests/fuzz/sanitizer_reports.py).
SANITIZED_TREE := build/sanitized
SANITIZER_REPORTS := $(abspath $(SANITIZED_TREE))/reports
SANITIZED_ENV := LD_PRELOAD="$$(gcc -print-file-name=libasan.so) $$(gcc -print-file-name=libubsan.so)" \
	ASAN_OPTIONS=detect_leaks=0:allocator_may_return_null=1:log_path=$(SANITIZER_REPORTS)/asan \
	UBSAN_OPTIONS=print_stacktrace=1:log_path=$(SANITIZER_REPORTS)/ubsan
fuzz-sanitized: $(VENV)/.stamp
	rm -rf $(SANITIZED_TREE) build/fuzz-sanitized && mkdir -p $(SANITIZED_TREE) $(SANITIZER_REPORTS) build/fuzz-sanitized
	cp -r csrc scripts skinkit tests setup.py pyproject.toml $(SANITIZED_TREE)/
	rm -f $(SANITIZED_TREE)/skinkit/*.so
	cd $(SANITIZED_TREE) && SKINKIT_SANITIZE=1 ../../$(PY) setup.py -q build_ext --inplace
	cd $(SANITIZED_TREE) && failed=0; \
		$(SANITIZED_ENV) ../../$(PY) -m tests.fuzz.binding_fuzz --calls $(FUZZ_SANITIZED_CALLS) \
			--out ../fuzz-sanitized --results ../fuzz-sanitized/results.json || failed=1; \
		$(SANITIZED_ENV) ../../$(PY) -m tests.fuzz.api_fuzz --calls $(FUZZ_SANITIZED_API_CALLS) \
			--seed $(FUZZ_SANITIZED_SEED) --out ../fuzz-sanitized --results ../fuzz-sanitized/results.json \
			|| failed=1; \
		../../$(PY) -m tests.fuzz.sanitizer_reports $(SANITIZER_REPORTS) || failed=1; \
		exit $$failed
FUZZ_SANITIZED_CALLS ?= 10000
FUZZ_SANITIZED_API_CALLS ?= 100
FUZZ_SANITIZED_SEED ?= 16

wheel: $(VENV)/.stamp
	rm -rf $(WHEEL_RAW_DIR) dist/skinkit-*.whl
	SKINKIT_WERROR=1 $(PY) -m pip wheel -q --no-deps --no-build-isolation -w $(WHEEL_RAW_DIR) .
	$(VENV)/bin/auditwheel repair --plat manylinux_2_34_x86_64 -w dist $(WHEEL_RAW_DIR)/skinkit-*.whl
	$(VENV)/bin/auditwheel show dist/skinkit-*manylinux*.whl

extension: $(EXTENSION)
$(EXTENSION): $(wildcard addon/* skinkit/*.py skinkit/*/*.py skinkit/*/*/*.py skinkit/*.pyi skinkit/shaders/*.glsl) $(shell find csrc -type f) setup.py LICENSE
	$(MAKE) wheel
	rm -f dist/skinkit-*.zip
	$(PY) scripts/build_extension.py dist/skinkit-*manylinux*.whl dist

demo: build
	$(PY) scripts/demo.py

# Benchmarks against the peers (requirements-bench.txt: py-dem-bones, xatlas, libigl); the data in ../shared/data is
# used when present and skipped with a message when not.
bench: build
	$(PY) -m pip install -q -r requirements-bench.txt
	$(PY) bench/bench_evaluate.py --markdown bench/evaluate_results.md --json bench/evaluate_results.json
	$(PY) bench/bench_fit.py --markdown bench/fit_results.md --json bench/fit_results.json
	$(PY) bench/profile_fit.py --json bench/profile_fit_results.json
	$(PY) bench/bench_metrics.py --markdown bench/metrics_results.md --json bench/metrics_results.json
	$(PY) bench/bench_decompose.py --markdown bench/decompose_results.md --json bench/decompose_results.json
	$(PY) bench/decompose_literature.py --markdown bench/decompose_literature_results.md --json bench/decompose_literature_results.json
	$(PY) bench/bench_unwrap.py --markdown bench/unwrap_results.md --json bench/unwrap_results.json
	$(PY) bench/bench_lod.py --markdown bench/lod_results.md --json bench/lod_results.json
	$(PY) bench/lod_variants.py > bench/lod_variants_results.md
	$(PY) bench/bench_lod_speed.py --markdown bench/lod_speed_results.md --json bench/lod_speed_results.json
	$(PY) bench/bench_limit_influences.py --markdown bench/limit_influences_results.md --json bench/limit_influences_results.json
	$(PY) bench/bench_runtime.py --markdown bench/runtime_results.md --json bench/runtime_results.json
	$(PY) bench/bench_blas_threads.py --markdown bench/blas_threads_results.md --json bench/blas_threads_results.json
	$(PY) bench/bench_skeleton.py --markdown bench/skeleton_results.md --json bench/skeleton_results.json
	$(PY) bench/bench_handles.py --markdown bench/handles_results.md --json bench/handles_results.json
	$(PY) bench/bench_bake.py --markdown bench/bake_results.md --json bench/bake_results.json
	$(PY) bench/bench_pack.py --markdown bench/pack_results.md --json bench/pack_results.json
	$(PY) bench/bench_batch.py --markdown bench/batch_results.md --json bench/batch_results.json

# How every offline stage grows from 10k to 1M vertices (bench/bench_scale.py, the synthetic creature of
# scripts/make_large_character.py): an hour or more, each stage in its own child under a timeout, so not in `bench`.
.PHONY: bench-scale
bench-scale: build
	$(PY) -m pip install -q -r requirements-bench.txt
	nice $(PY) bench/bench_scale.py --timeout 600 --memory-limit 8G --markdown bench/scale_results.md \
		--json bench/scale_results.json --plot docs/images/scale.png

samples: venv
	$(PY) blend_samples/make_samples.py --out blend_samples

clean:
	rm -rf build dist skinkit/*.so .pytest_cache

# clang and Windows (MinGW-w64 + Wine) builds of the C core: make test-portability.
include portability.mk
