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

.PHONY: all bootstrap build demo test bench model fuzz fmt clean

all: build

bootstrap:
	@./scripts/bootstrap.sh

build: bootstrap
	$(CARGO) build --release --locked

demo: build
	./target/release/geostride demo --out out/demo
	./target/release/geostride demo --crowd --out out/demo
	./target/release/geostride demo --crowd --detector simulated --out out/demo
	./target/release/geostride demo --group --out out/demo
	./target/release/geostride demo --group --detector onnx --out out/demo

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
	$(PYTHON) -m venv out/bench-venv
	out/bench-venv/bin/pip install -q --disable-pip-version-check -r benches/requirements.txt
	GEOSTRIDE_PYCOLMAP_PYTHON=$(CURDIR)/out/bench-venv/bin/python $(CARGO) bench --locked --bench sfm_vs_colmap
	$(CARGO) build --release --locked
	$(PYTHON) benches/sfm_scale.py out/sfm-scale --pycolmap-python out/bench-venv/bin/python
	./scripts/pets-benchmark.sh out/pets-benchmark
	$(CARGO) bench --locked --bench detect_vs_opencv
	$(CARGO) bench --locked --bench overhead_detector
	$(CARGO) bench --locked --bench gcp_targets

# The overhead person detector's recipe (docs/detector.md): tiles from the simulator (training
# seed 1 at the model's scales, then seed 5 with grounds up to the feature-rich texture scenes
# give structure from motion; validation seed 2 in 1024-px tiles at the model's scales and at
# all scales), then scripts/train_detector.py on 2 CPU threads with Debian's PyTorch, in three
# phases (each from the last one's weights; the second and third at a lower learning rate).
# Writes out/model/overhead-person.onnx and its report (about 110 minutes on 2 cores).
PYTHON ?= /usr/bin/python3
MODEL_TILES ?= 10000
MODEL_EPOCHS ?= 14
MODEL_EPOCHS_2 ?= 6
MODEL_EPOCHS_3 ?= 8
MODEL_VAL = --val out/model/val --val-all out/model/val-all --batch 16 --threads 2
model: build
	rm -rf out/model && mkdir -p out/model
	./target/release/geostride dataset --out out/model/train --tiles $(MODEL_TILES) --seed 1 --gsd-cm 1.2,3
	./target/release/geostride dataset --out out/model/train-textured --tiles $(MODEL_TILES) --seed 5 \
	  --gsd-cm 1.2,3 --ground-detail 0.6,5
	./target/release/geostride dataset --out out/model/val --tiles 150 --size 1024 --seed 2 --gsd-cm 1.2,3 \
	  --ground-detail 0.6,5
	./target/release/geostride dataset --out out/model/val-all --tiles 150 --size 1024 --seed 2 \
	  --ground-detail 0.6,5
	$(PYTHON) scripts/train_detector.py --train out/model/train $(MODEL_VAL) \
	  --out out/model/phase1.onnx --epochs $(MODEL_EPOCHS) --report out/model/phase1.json
	$(PYTHON) scripts/train_detector.py --train out/model/train $(MODEL_VAL) \
	  --weights out/model/phase1.onnx.pt --lr 5e-4 \
	  --out out/model/phase2.onnx --epochs $(MODEL_EPOCHS_2) --report out/model/phase2.json
	$(PYTHON) scripts/train_detector.py --train out/model/train-textured $(MODEL_VAL) \
	  --weights out/model/phase2.onnx.pt --lr 5e-4 \
	  --out out/model/overhead-person.onnx --epochs $(MODEL_EPOCHS_3) --report out/model/report.json

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
