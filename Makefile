# PHRT for Blender. The two README commands: `make demo` and `make test`.
# Both create .venv with the machine's python3 (3.11) if missing and install the
# pinned dependencies once (a stamp file makes the second run quick).

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.phrt-installed

.PHONY: demo test test-fast bench soak extension scenes clean

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

# Long runs kept out of `make test` (tools/soak.py): a 1000-frame HYBRID replay of arcade at
# 320x240, budget 600 ms (RSS after frame 100 vs 1000 < 50 MB, GPU/Embree objects created ==
# freed) and a 2-million-triangle mesh in the three modes. ~15 min on 2 cores; figures in
# out/soak/soak.json.
soak: $(STAMP)
	$(PY) tools/soak.py --out out/soak

scenes: $(STAMP)
	$(VENV)/bin/phrt scenes

# One extension zip per platform, with the wheels it needs (never committed).
extension: $(STAMP)
	$(PY) tools/build_extension.py --platforms all --out dist

clean:
	rm -rf out dist wheels .pytest_cache
