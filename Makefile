# geostride: `make demo` runs the bundled example, `make test` the tests (and the pure core
# alone, built without OpenCV, GDAL, PROJ or ONNX Runtime: scripts/check-pure.sh), `make bench` the
# side-by-side benchmarks. Each target first installs what the build needs (scripts/bootstrap.sh).

CARGO ?= cargo

# Real third-party data for tests and benchmarks (see ../shared/data/README.md), when present.
ifeq ($(origin GEOSTRIDE_DATA), undefined)
  ifneq ($(wildcard ../shared/data),)
    export GEOSTRIDE_DATA := $(abspath ../shared/data)
  endif
endif

.PHONY: all bootstrap build demo test bench fuzz fmt clean

all: build

bootstrap:
	@./scripts/bootstrap.sh

build: bootstrap
	$(CARGO) build --release --locked

demo: build
	./target/release/geostride demo --out out/demo
	./target/release/geostride demo --crowd --out out/demo
	./target/release/geostride demo --group --out out/demo

test: bootstrap
	$(CARGO) test --release --locked
	CARGO=$(CARGO) ./scripts/check-pure.sh

bench: bootstrap
	@./scripts/bootstrap.sh --bench
	$(CARGO) bench --locked --bench calibrate_vs_opencv
	$(CARGO) bench --locked --bench pnp_vs_opencv
	$(CARGO) bench --locked --bench simulate
	$(CARGO) bench --locked --bench pipeline_throughput
	$(CARGO) bench --locked --bench cluster_scaling
	$(CARGO) bench --locked --bench ba_vs_ceres
	$(CARGO) bench --locked --bench sfm_vs_colmap
	./scripts/pets-benchmark.sh out/pets-benchmark
	$(CARGO) bench --locked --bench detect_vs_opencv

# The long fuzzing run: 10^6 inputs per parser (about 45 minutes on 2 cores, most of it crs through
# PROJ), then every command on 200 MB inputs with its peak memory measured. `make test` runs a
# bounded version.
fuzz: build
	$(CARGO) run --release --locked --example fuzz -- --inputs 1000000
	$(CARGO) run --release --locked --example fuzz -- --big --mb 200

fmt:
	$(CARGO) fmt

clean:
	$(CARGO) clean
	rm -rf out
