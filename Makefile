# causalcity: the two set-up commands are `make dataset` and `make test`.
CARGO ?= cargo
# Cargo features: hdf5 turns on `export vcdn` and needs the system HDF5
# library, which the system-deps target installs. `make FEATURES= ...` builds
# without it (and installs nothing).
FEATURES ?= hdf5
CARGO_FEATURES := $(if $(strip $(FEATURES)),--features "$(FEATURES)",)
# Through cargo so that CARGO_TARGET_DIR and friends are respected.
RUN := $(CARGO) run --release --locked --quiet $(CARGO_FEATURES) --
# The built binary itself, for figures that time or count a whole process
# (cargo's own start-up would be in them through $(RUN)).
BIN := $(or $(CARGO_TARGET_DIR),target)/release/causalcity

.PHONY: all build install system-deps dataset test test-rust test-python python-env wheel paper bench bench-instructions bench-methods bench-gpu bench-gpu-paper bench-original-nri counterfactual-table fuzz lint fmt clean
PYTHON ?= python3
VENV := target/python-venv
PYDATA := target/python-data

all: build

## System libraries for the chosen features (HDF5 via apt-get or brew).
system-deps:
ifneq ($(filter hdf5,$(FEATURES)),)
	sh tools/install-system-deps.sh
endif

build: system-deps
	$(CARGO) build --release --locked $(CARGO_FEATURES)

## Put the causalcity binary on the PATH (cargo's bin folder, ~/.cargo/bin).
install: system-deps
	$(CARGO) install --path . --locked $(CARGO_FEATURES)
	@command -v causalcity >/dev/null || echo "note: add $${CARGO_HOME:-$$HOME/.cargo}/bin to your PATH"

## Generate the small built-in toy and city datasets into data/ci-toy and data/ci-city.
dataset: build
	$(RUN) gen --spec configs/ci-toy.json --out data/ci-toy
	$(RUN) gen --spec configs/ci-city.json --out data/ci-city
	@echo "datasets written to data/ci-toy and data/ci-city (see docs/output-layout.md)"

## Run every test: Rust (unit, integration on real files) and the Python client tests.
test: test-rust test-python

test-rust: system-deps
	$(CARGO) test --locked $(CARGO_FEATURES)

## Python clients (numpy, pandas, Pillow, pycocotools, h5py from PyPI, in a venv under target/)
## load a small generated dataset and its exports; the Python package
## (python/, installed with pip) must give the same values as those files.
test-python: build python-env
	rm -rf $(PYDATA)
	$(RUN) gen --quiet --annotations --spec tests/python/toy.json --out $(PYDATA)/toy
	$(RUN) gen --quiet --spec tests/python/city.json --out $(PYDATA)/city
	$(RUN) export nri $(PYDATA)/toy --out $(PYDATA)/nri-causalcity
	$(RUN) export nri $(PYDATA)/toy --out $(PYDATA)/nri-reference --layout nri --directed
	$(RUN) export nri $(PYDATA)/toy --out $(PYDATA)/nri-original --clip --velocity forward --suffix _airsim_final
	$(RUN) export nri $(PYDATA)/city --out $(PYDATA)/nri-dynamic --dynamic --directed
	$(RUN) export nsdr $(PYDATA)/toy --out $(PYDATA)/nsdr --quiet
	$(RUN) export nsdr $(PYDATA)/city --out $(PYDATA)/nsdr-city --quiet
	$(if $(filter hdf5,$(FEATURES)),$(RUN) export vcdn $(PYDATA)/toy --out $(PYDATA)/vcdn --quiet)
	$(RUN) counterfactual --scenario configs/examples/stop-the-leader.json --out $(PYDATA)/counterfactual
	$(RUN) counterfactual --sweep tests/python/city.json --no-images --quiet --kinds remove,stop --out $(PYDATA)/sweep
	$(RUN) run --scenario configs/examples/cameras.json --out $(PYDATA)/cameras
	CAUSALCITY_DATA=$(PYDATA) CAUSALCITY_CLI='$(RUN)' $(VENV)/bin/python -m pytest -q -p no:cacheprovider -W ignore::DeprecationWarning:pycocotools.mask tests/python python/tests

## A venv under target/ with the test clients' packages and the Python
## package itself with its reference methods, installed as README says
## (pip install "./python[methods]": PyTorch from PyPI, ~1 minute, ~5 GB).
python-env:
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check -r tests/python/requirements.txt
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check "./python[methods]"

## A wheel of the Python package into target/wheels: one file for CPython
## 3.9 and later (the stable ABI, abi3), tagged manylinux where the build
## allows, which `pip install` takes on a machine without Rust.
WHEELS := target/wheels
wheel: python-env
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check "maturin>=1.9,<2"
	rm -rf $(WHEELS)
	$(VENV)/bin/maturin build --release --locked --quiet --manifest-path python/Cargo.toml --out $(WHEELS)
	@ls $(WHEELS)/*.whl

## The paper's experiments on toy and city: datasets, every reference method
## trained and evaluated, results CSV, figures and Markdown table under
## results/. Quick by default (about 55 min on 2 cores, projected by --plan); the paper's full
## 4000/500/500 setting: make paper PAPER_FLAGS="--device cuda".
PAPER_FLAGS ?= --quick
paper: python-env
	$(VENV)/bin/python -m causalcity.paper $(PAPER_FLAGS)

## Throughput, memory and size figures (prints, asserts nothing); then the
## Python package's rates beside the command line's; then issue 23's ground
## truth figures (effects backing the design, the learned leak classifiers);
## then poses-only gen beside SUMO (eclipse-sumo from PyPI, ~100 MB, into the venv).
bench: build python-env
	$(CARGO) bench --locked $(CARGO_FEATURES) --bench throughput
	CAUSALCITY_CLI='$(RUN)' $(VENV)/bin/python benches/python_throughput.py
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check eclipse-sumo
	CAUSALCITY_CLI='$(BIN)' $(VENV)/bin/python benches/sumo_side_by_side.py
	CAUSALCITY_CLI='$(RUN)' $(VENV)/bin/python benches/ground_truth.py

## Instructions a poses-only and an effects `gen` job execute (valgrind's
## callgrind; repeats exactly where wall time on a shared VM does not).
## BASE_CLI=path/to/older/causalcity measures it beside this build.
bench-instructions: build
	CAUSALCITY_CLI='$(BIN)' python3 benches/instructions.py

## The reference methods' own figures (prints, asserts nothing): NRI's
## training throughput today against an earlier revision's, learning at a
## large batch against a small one, and NRI on NRI's springs benchmark
## (about 30 min on 2 cores; BENCH_DEVICE=cuda on a GPU). See the script.
bench-methods: python-env
	$(VENV)/bin/python benches/nri_methods.py

## Issue 35's GPU figures in one run of about 10 minutes on one H100-class
## GPU: the full setting's projection, one NRI epoch at the paper's size
## (eager against CUDA graphs), NRI and NRI with trail messages against
## the path rule and Granger on the full-size toy, and NRI on NRI's springs
## at NRI's size. See the script.
bench-gpu: python-env
	PYTHON=$(VENV)/bin/python bash benches/gpu_check.sh

## The paper's full setting on one GPU, one group (cars08_edges50) within a
## time budget (PAPER_SECONDS, default 540): NRI on toy and city first, the
## CPU methods beside it; the finished units land in results/paper-gpu.
bench-gpu-paper: python-env
	PYTHON=$(VENV)/bin/python bash benches/gpu_paper.sh

## The counterfactual task's reference table (docs/evaluation.md): its
## sweep, the three reference methods, their scores and times (prints,
## asserts nothing; about 2 minutes on 2 cores).
counterfactual-table: build python-env
	CAUSALCITY_CLI='$(RUN)' $(VENV)/bin/python benches/counterfactual_task.py

## NRI's own public code against ours on the same springs and toy data
## (prints, asserts nothing; about 30 min on 2 cores). Needs a checkout of
## it: NRI_CHECKOUT=/path/to/NRI (git clone https://github.com/ethanfetaya/NRI).
bench-original-nri: build python-env
	CAUSALCITY_CLI='$(RUN)' $(VENV)/bin/python benches/original_nri.py

## Fuzz the spec parser and the predictions-file reader of `evaluate` (not
## part of CI), FUZZ_SECONDS each (default 600). Installs cargo-fuzz if
## missing (and says so); runs on stable through RUSTC_BOOTSTRAP; refuses
## to run rather than rewrite the tracked fuzz/Cargo.lock. The predictions
## target fails any single allocation over 512 MB (-malloc_limit_mb), so
## that a declared size the reader believed would show as a crash.
FUZZ_SECONDS ?= 600
fuzz:
	@command -v cargo-fuzz >/dev/null || { echo "make fuzz: installing cargo-fuzz (cargo install cargo-fuzz --locked, a few minutes)"; $(CARGO) install cargo-fuzz --locked; }
	cd fuzz && $(CARGO) metadata --locked --format-version 1 >/dev/null || { echo "fuzz/Cargo.lock is out of date with the crate: run 'cd fuzz && cargo update -w' and commit it"; exit 1; }
	@echo "make fuzz: fuzzing the spec parser for $(FUZZ_SECONDS) s (FUZZ_SECONDS=N to change)"
	cd fuzz && RUSTC_BOOTSTRAP=1 $(CARGO) fuzz run spec corpus/spec -- -max_total_time=$(FUZZ_SECONDS) -max_len=4096
	@echo "make fuzz: fuzzing the predictions reader (.npz) for $(FUZZ_SECONDS) s"
	cd fuzz && RUSTC_BOOTSTRAP=1 $(CARGO) fuzz run predictions corpus/predictions -- -max_total_time=$(FUZZ_SECONDS) -max_len=65536 -rss_limit_mb=2048 -malloc_limit_mb=512

lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --locked --all-targets $(CARGO_FEATURES) -- -D warnings

fmt:
	$(CARGO) fmt --all

clean:
	$(CARGO) clean
	rm -rf data
