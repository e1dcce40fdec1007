# Two commands do all set-up on a fresh Debian machine with Python 3.11: `make demo` and `make test`.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
export CI ?= true
export RERUN_ANALYTICS ?= 0

.PHONY: setup browser demo test test-faults lint typecheck bench bench-stream bench-long bench-io bench-mcpnet bench-objects bench-cracks bench-lrgnet bench-transfer bench-batch bench-real bench-all train screenshot clean

setup: $(STAMP)

# open3d's module needs libusb-1.0 from Debian; torch==2.13.0 takes the local CPU wheel where pip offers one.
$(STAMP): pyproject.toml
	@dpkg -s libusb-1.0-0 >/dev/null 2>&1 || { $(SUDO) apt-get update -q && $(SUDO) apt-get install -y -q libusb-1.0-0; }
	@[ -x $(BIN)/python ] || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --disable-pip-version-check --upgrade pip
	$(BIN)/pip install -q --disable-pip-version-check -e '.[dev]'
	@touch $(STAMP)

demo: setup
	$(BIN)/aftershock run --save out/demo.rrd --export out/demo --force

# The report's page is checked in headless Chromium (Debian's package, driven by playwright from the dev extras).
browser:
	@command -v chromium >/dev/null || { $(SUDO) apt-get update -q && $(SUDO) apt-get install -y -q chromium; }

# mypy (below) takes about a minute of one core from a fresh clone, seconds with its cache in .mypy_cache.
# The suite runs on every core (pytest-xdist), a test file to a worker: a file's fixtures are built once.
TEST_WORKERS ?= logical
test: setup browser
	$(BIN)/ruff check .
	$(MYPY)
	$(BIN)/pytest -q -n $(TEST_WORKERS) --dist loadfile

# Faults and hostile input on their own (also part of `make test`): full disks through a small tmpfs (needs root,
# skipped otherwise), SIGINT/SIGTERM/SIGKILL mid-run, truncated and corrupted logs, hostile headers and settings.
test-faults: setup
	$(BIN)/pytest -q -rs tests/test_faults.py

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(MYPY)

# mypy on the installed names (pyproject.toml [tool.mypy]). The editable install maps `aftershock.*` with an import
# hook that mypy cannot follow, so a link `aftershock` to this folder stands in; the report names the files as here.
MYPY_PATH := $(VENV)/mypy-path
MYPY = @mkdir -p $(MYPY_PATH) && ln -sfn $(CURDIR) $(MYPY_PATH)/aftershock && \
	MYPYPATH=$(MYPY_PATH) $(BIN)/mypy > $(MYPY_PATH)/report.txt; rc=$$?; \
	sed 's|^$(MYPY_PATH)/aftershock/||' $(MYPY_PATH)/report.txt; exit $$rc
typecheck: setup
	$(MYPY)

# Speed and memory of the whole stream (VLP-16 simulated missions with Rerun recording to a file).
bench: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_pipeline.py

# Its halves: the 300-scan stream against KISS-ICP alone (sequential and overlapped), and the 3,000-scan
# mission (memory, compacted recording, web viewer picture; needs `pip install -e '.[screenshot]'` and chromium).
bench-stream: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_pipeline.py -k whole_stream

bench-long: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_pipeline.py -k long_mission

# Decoding, simulation and sink throughput.
bench-io: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_sources.py tests/bench/bench_simulator.py tests/bench/bench_sinks.py

bench-mcpnet: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_mcpnet.py

# Objects shown against true objects (instance precision/recall) on held-out missions, KISS-ICP and true poses.
bench-objects: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_objects.py

bench-cracks: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_cracks_region.py tests/bench/bench_cracks_ridge.py tests/bench/bench_cracks.py

bench-lrgnet: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_lrgnet.py

# In-family against a scene generator no network was trained or tuned on, with and without colour.
bench-transfer: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_transfer.py

# Many missions at once: 8 simulated 300-scan missions on a local Ray instance, 2 workers against 1.
bench-batch: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_batch.py

# Every real log in ../shared/data/lidar: floor, ceiling and wall agreement with planes found without the labeller
# (pipeline.planecheck), the class shares of each map, the run's warnings (REAL_ARGS: options for every run).
bench-real: setup
	$(BIN)/pytest -q -m slow -s tests/bench/bench_real.py

bench-all: bench bench-io bench-mcpnet bench-objects bench-cracks bench-lrgnet bench-transfer bench-batch bench-real

# Rebuild every network from simulator data into out/weights (the shipped files in models/weights are left alone;
# run the pipeline on the rebuilt ones with --set label.weights=out/weights/mcpnet.pt and the like).
TRAINED := out/weights
train: setup
	@mkdir -p $(TRAINED)
	$(BIN)/aftershock train mcpnet --out $(TRAINED)/mcpnet.pt --force
	$(BIN)/aftershock train lrgnet --out $(TRAINED)/lrgnet.pt --force
	$(BIN)/aftershock train crackembed --out $(TRAINED)/crackembed.pt --force
	$(BIN)/python -m aftershock.models.scan_reference_train $(TRAINED)/scan_reference.json
	$(BIN)/python -m aftershock.models.compare_weights models/weights $(TRAINED)

# The README picture: the demo recording in Rerun's web viewer, headless (needs Debian's chromium).
screenshot: demo
	@command -v chromium >/dev/null || { $(SUDO) apt-get update -q && $(SUDO) apt-get install -y -q chromium; }
	$(BIN)/pip install -q -e '.[screenshot]'
	$(BIN)/python ../shared/tools/rrd_screenshot.py out/demo.rrd docs/demo.png --wait 60

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache
