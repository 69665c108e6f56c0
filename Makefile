# PHRT for Blender. The two README commands: `make demo` and `make test`.
# Both create .venv with the machine's python3 (3.11) if missing and install the
# pinned dependencies once (a stamp file makes the second run quick).

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.phrt-installed

.PHONY: demo test test-fast bench paper extension scenes clean

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

# The paper's experiment on both sample scenes: 2 scenes x 3 paths x 3 modes x 1000 frames at
# 640x480, a 5-budget sweep of path1 of each, one report in out/paper/report/.  LONG: many hours
# on 2 cores (about a second per frame); not part of `make test`.  Interrupted, it resumes:
# complete runs are skipped.  `python -m phrt.paper --help` for a shorter one.
paper: $(STAMP)
	$(PY) -m phrt.paper --out out/paper

scenes: $(STAMP)
	$(VENV)/bin/phrt scenes

# One extension zip per platform, with the wheels it needs (never committed).
extension: $(STAMP)
	$(PY) tools/build_extension.py --platforms all --out dist

clean:
	rm -rf out dist wheels .pytest_cache
