# PHRT for Blender. The two README commands: `make demo` and `make test`.
# Both create .venv with the machine's python3 (3.11) if missing and install the
# pinned dependencies once (a stamp file makes the second run quick).

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.phrt-installed
BLENDER_EXT := $(VENV)/lib/python3.11/site-packages/bpy/5.0/scripts/addons_core/bl_pkg/cli/blender_ext.py

.PHONY: demo test test-fast bench extension scenes clean

$(STAMP): requirements.txt pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt
	$(PY) -m pip install -q --no-deps -e .
	@touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(PY) -m phrt.demo --out out/demo

test: $(STAMP)
	$(PY) -m pytest -q

# Core unit tests only (no Blender): seconds.
test-fast: $(STAMP)
	$(PY) -m pytest -q tests/core

bench: $(STAMP)
	$(PY) -m phrt.bench

scenes: $(STAMP)
	$(VENV)/bin/phrt scenes

# One extension zip per platform, with the wheels it needs (never committed).
extension: $(STAMP)
	$(PY) tools/fetch_wheels.py --dest wheels
	$(PY) $(BLENDER_EXT) validate .
	mkdir -p dist
	$(PY) $(BLENDER_EXT) build --source-dir . --output-dir dist --split-platforms

clean:
	rm -rf out dist wheels .pytest_cache
