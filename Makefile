# Two commands do all set-up on a fresh machine (idempotent):
#   make demo   - venv if missing, then simulate the example cave scene, reconstruct, mesh + metrics
#   make test   - venv if missing, then pytest (slow cases skipped; `make test-all` runs them)
PYTHON ?= python3.11
VENV   ?= .venv
PY     := $(VENV)/bin/python
# The torch build is an explicit choice: TORCH=cpu (default) or TORCH=cuda (CUDA=cu128 picks the
# CUDA index). Switching TORCH re-installs (the stamp carries it).
TORCH  ?= cpu
CUDA   ?= cu128
TORCH_VERSION := 2.13.0
ifeq ($(TORCH),cpu)
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu
else ifeq ($(TORCH),cuda)
TORCH_INDEX ?= https://download.pytorch.org/whl/$(CUDA)
else
$(error TORCH must be cpu or cuda, not '$(TORCH)')
endif
PIP    := $(PY) -m pip install --disable-pip-version-check --progress-bar on
STAMP  := $(VENV)/.installed-$(TORCH)-$(shell cat pyproject.toml requirements/*.txt 2>/dev/null | cksum | cut -d' ' -f1)
DEMO_OUT ?= out/demo
DEMO_RES ?= 128

.PHONY: venv torch demo test test-all bench bench-quick addon-zip clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found; bpy 5.0.1 needs exactly Python 3.11 (set PYTHON=/path/to/python3.11)"; exit 1; }
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(MAKE) --no-print-directory torch
	$(PIP) -e ".[blender,dev]"
	@rm -f $(VENV)/.installed-*
	@touch $@

# torch first, pinned (a loose pin would pull the newest CUDA build and GBs of NVIDIA packages).
# cpu: a CPU wheel of the pin that pip already resolves without an index (a wheel cache or
# find-links, as on CI and the project machines) is used as is; otherwise the CPU index.
# cuda: always the CUDA index.
torch:
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@if [ "$(TORCH)" = cpu ] && $(PY) -m pip install --disable-pip-version-check --dry-run --no-deps --no-index --ignore-installed "torch==$(TORCH_VERSION)" >/dev/null 2>&1; then \
	  echo "torch $(TORCH_VERSION) (cpu): local wheel"; \
	  $(PIP) "torch==$(TORCH_VERSION)"; \
	else \
	  echo "torch $(TORCH_VERSION) ($(TORCH)): $(TORCH_INDEX)"; \
	  $(PIP) --index-url $(TORCH_INDEX) "torch==$(TORCH_VERSION)"; \
	fi

demo: venv
	$(PY) examples/run_demo.py --out $(DEMO_OUT) --resolution $(DEMO_RES)

test: venv
	$(PY) -m pytest -m "not slow" -q

test-all: venv
	$(PY) -m pytest -q

# every benchmark suite (benchmarks/suites/) -> benchmarks/results/*.json + .png, then the README/docs tables
# from them; bench-quick: smoke runs -> benchmarks/results/quick/ (docs/benchmarks.md)
bench: venv
	$(PY) -m benchmarks all; rc=$$?; $(PY) -m benchmarks readme; exit $$rc

bench-quick: venv
	$(PY) -m benchmarks all --quick

# one extension zip per Blender platform with the simulator's wheels (cached in .cache/blender_wheels);
# ADDON_PLATFORM=linux-x64 (or macos-arm64, macos-x64, windows-x64) builds just one
ADDON_PLATFORM ?= all
addon-zip: venv
	$(PY) addon/build_zip.py --out dist --platform $(ADDON_PLATFORM)

clean:
	rm -rf out dist .pytest_cache
