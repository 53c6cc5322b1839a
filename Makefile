# Two commands do all set-up on a fresh machine (idempotent):
#   make demo   - venv if missing, then simulate the example cave scene, reconstruct, mesh + metrics
#   make test   - venv if missing, then pytest (slow cases skipped; `make test-all` runs them)
PYTHON ?= python3.11
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-$(shell cat pyproject.toml requirements/*.txt 2>/dev/null | cksum | cut -d' ' -f1)
DEMO_OUT ?= out/demo
DEMO_RES ?= 64

.PHONY: venv demo test test-all bench bench-quick addon-zip clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found; bpy 5.0.1 needs exactly Python 3.11 (set PYTHON=/path/to/python3.11)"; exit 1; }
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	# torch first, pinned: the CPU wheel; any other version would pull several GB of CUDA packages
	$(PY) -m pip install --disable-pip-version-check -q "torch==2.13.0"
	$(PY) -m pip install --disable-pip-version-check -q -e ".[blender,dev]"
	@rm -f $(VENV)/.installed-*
	@touch $@

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

addon-zip: venv
	$(PY) addon/build_zip.py --out dist

clean:
	rm -rf out dist .pytest_cache
