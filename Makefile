# vcsim top-level entry points. `make run` and `make test` work on a fresh Debian 12 machine.
JOBS ?= $(shell nproc)
WERROR ?= $(if $(CI),ON,OFF)

.PHONY: all deps build build-asan build-fuzz run test test-release test-asan test-fuzz test-tsan \
        fuzz-long bench format clean

all: build

deps:
	@scripts/install-deps

build: deps
	cmake --preset release -DVCSIM_WERROR=$(WERROR)
	cmake --build --preset release -j $(JOBS)

build-asan: deps
	cmake --preset asan -DVCSIM_WERROR=$(WERROR)
	cmake --build --preset asan -j $(JOBS)

# The parsers' libFuzzer targets (tests/fuzz): clang-14, only the parsers' sources.
build-fuzz: deps
	cmake --preset fuzz
	cmake --build --preset fuzz -j $(JOBS)

# The main job: the default scenario headless (data/scenarios/default.json). Frames and metrics
# go to out/default/. Exit status 3 means it ran but did not reach every landmark (reported).
run: build
	@build/bin/vcsim run default --out out/default; s=$$?; [ $$s -eq 0 ] || [ $$s -eq 3 ]

test: test-release test-asan test-fuzz test-tsan

test-release: build
	ctest --preset release -j $(JOBS)

test-asan: build-asan
	ctest --preset asan -j $(JOBS)

# A short run of each fuzz target from its seed corpus (6 s each); a crash fails the test.
test-fuzz: build-fuzz
	ctest --preset fuzz -j $(JOBS)

# A longer campaign: each target for FUZZ_SECONDS or FUZZ_RUNS executions, whichever comes first
# (-1: no limit); docs/measurements.md has the last figures.
FUZZ_SECONDS ?= 300
FUZZ_RUNS ?= -1
fuzz-long: build-fuzz
	tests/fuzz/run-campaign build-fuzz $(FUZZ_SECONDS) $(FUZZ_RUNS)

# ThreadSanitizer on the tests that use threads only (the tsan preset builds just those).
test-tsan: deps
	cmake --preset tsan -DVCSIM_WERROR=$(WERROR)
	cmake --build --preset tsan -j $(JOBS)
	ctest --preset tsan -j $(JOBS)

bench: build
	build/bin/vcsim_bench_rod --benchmark_min_time=0.2
	build/bin/vcsim_bench_solver --benchmark_min_time=0.5
	build/bin/vcsim_bench_sim
	build/bin/vcsim bench rod --nodes 256
	build/bin/vcsim bench compression

format:
	clang-format -i $$(git ls-files '*.cpp' '*.h')

clean:
	rm -rf build build-debug build-asan build-fuzz build-tsan
