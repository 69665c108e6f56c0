# PHRT for Blender. The two README commands: `make demo` and `make test`.
# Both create .venv with the machine's python3 (3.11) if missing and install the
# pinned dependencies once (a stamp file makes the second run quick).

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.phrt-installed

.PHONY: demo test test-fast test-compat bench paper soak faults extension scenes clean selection-eval rate-flip tiers-ceiling

$(STAMP): requirements.txt pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	tools/pip_install $(PY) -q --upgrade pip
	tools/pip_install $(PY) -q -r requirements.txt
	$(PY) -m pip install -q --no-deps -e .
	@touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(PY) -m phrt.cli.demo --out out/demo

test: $(STAMP)
	$(PY) -m pytest -q

# Core unit tests only (no Blender): seconds.
test-fast: $(STAMP)
	$(PY) -m pytest -q tests/core

bench: $(STAMP)
	$(PY) -m phrt.cli.bench

# The paper's experiment on both sample scenes: 2 scenes x 3 paths x 3 modes x 1000 frames at
# 640x480, a 5-budget sweep of path1 of each, one report in out/paper/report/.  LONG: many hours
# on 2 cores (about a second per frame); not part of `make test`.  Interrupted, it resumes:
# complete runs are skipped.  `python -m phrt.cli.paper --help` for a shorter one.
# `make paper WORKERS=N` runs it on a Dask LocalCluster of N worker processes, `make paper
# SCHEDULER=tcp://HOST:8786` on an existing Dask cluster (docs/cluster.md).
paper: $(STAMP)
	$(PY) -m phrt.cli.paper --out out/paper $(if $(WORKERS),--workers $(WORKERS)) $(if $(SCHEDULER),--scheduler $(SCHEDULER))

# Long runs kept out of `make test` (tools/soak.py): a 1000-frame HYBRID replay of arcade at
# 320x240, budget 600 ms (RSS after frame 100 vs 1000 < 50 MB, GPU/Embree objects created ==
# freed) and a 2-million-triangle mesh in the three modes. ~15 min on 2 cores; figures in
# out/soak/soak.json.
soak: $(STAMP)
	$(PY) tools/soak.py --out out/soak

# SIGKILL 20 replays at random moments (while an image, a CSV row or summary.json is being
# written, or at a random time): every run folder must read back consistently and the report must
# take it as partial (tools/faults.py; a 4-kill version runs in `make test`). ~5 min on 2 cores.
faults: $(STAMP)
	$(PY) tools/faults.py --kills 20 --out out/faults

# The selections judged on the held-out paths (issue 20): sweeps at 320x240, budgets 0.1-0.9 of the
# way, the oracle every 4th frame, variants measured, error, benefit; one table of captured share
# (90% interval), pops / 100 frames and p95 / budget in out/selection-eval/selection_eval.{csv,md}.
# LONG (hours at the default 240 frames per path); resumes.  It keeps every frame of every run
# as EXR: about 11 GB of disk at 200 frames a path (the report is scored from them; delete the
# runs' frames/ folders once the table is written if the disk is small).  A short one:
# `make selection-eval EVAL_FRAMES=1-48 EVAL_PATHS=arcade/path3`.
EVAL_FRAMES ?= 1-240
EVAL_PATHS ?= arcade/path3,atrium/path2,atrium/path3,showcase/orbit
selection-eval: $(STAMP)
	$(PY) tools/selection_eval.py --out out/selection-eval --frames $(EVAL_FRAMES) --paths $(EVAL_PATHS)

# What each quality-tier rate loses per effect on the judged paths (LDR-FLIP against full rate;
# a picture of one frame at each rate): out/rate-flip/rate_flip.{csv,md}.  Minutes; after
# selection-eval (it reuses that folder's orbiting showcase scene).
rate-flip: $(STAMP)
	$(PY) tools/rate_flip.py --out out/rate-flip --frames $(EVAL_FRAMES)

# The most any choice of rates could buy at each budget (issue 23's ceiling): every (element,
# effect) item of every 4th frame traced alone at each rate, the best combination chosen exactly
# and rendered: out/tiers-ceiling/tiers_ceiling.{md,csv}.  About 20 minutes; after selection-eval.
tiers-ceiling: $(STAMP)
	$(PY) tools/tiers_ceiling.py --eval out/selection-eval --every 4 --budget-at 0.1,0.25,0.5 --out out/tiers-ceiling

scenes: $(STAMP)
	$(VENV)/bin/phrt scenes

# One extension zip per platform, with the wheels it needs (never committed).
extension: $(STAMP)
	$(PY) tools/build_extension.py --platforms all --out dist

# The Blender versions PHRT supports (README "Blender versions"): for each, the bpy
# wheel, its Python and the numpy it allows.  `make test-compat` runs the whole
# suite once per version, each in its own reused .venv-blender-X.Y with this
# checkout installed in editable mode; `make test-compat COMPAT_VERSIONS=4.5`
# runs one.  A missing Python is found by tools/find_python (PATH, pyenv, uv) or
# given as `make test-compat PYTHON_3.13=/path/to/python3.13`.
COMPAT_MATRIX := 4.5 5.0 5.2
COMPAT_VERSIONS := $(COMPAT_MATRIX)
COMPAT_BPY_4.5 := 4.5.15
COMPAT_PYTHON_4.5 := 3.11
COMPAT_NUMPY_4.5 := 1.26.4
COMPAT_BPY_5.0 := 5.0.1
COMPAT_PYTHON_5.0 := 3.11
COMPAT_NUMPY_5.0 := 1.26.4
COMPAT_BPY_5.2 := 5.2.3
COMPAT_PYTHON_5.2 := 3.13
COMPAT_NUMPY_5.2 := 2.5.5

# requirements.txt with this version's bpy and numpy; a venv made by another
# Python is made anew.
.venv-blender-%/.phrt-installed: requirements.txt pyproject.toml Makefile
	@test -n "$(COMPAT_BPY_$*)" || { echo "make: Blender $* is not in the matrix: use one of $(COMPAT_MATRIX)" >&2; exit 2; }
	@set -e; python="$(PYTHON_$(COMPAT_PYTHON_$*))"; \
	if [ -z "$$python" ]; then python=$$(tools/find_python $(COMPAT_PYTHON_$*)); fi; \
	if [ -x $(@D)/bin/python ] && ! $(@D)/bin/python -c 'import sys; sys.exit(sys.version_info[:2] != ($(subst .,$(comma),$(COMPAT_PYTHON_$*))))'; then \
		echo "$(@D) was made by another Python: making it anew with $$python"; rm -rf $(@D); fi; \
	test -x $(@D)/bin/python || { echo "$$python -m venv $(@D)"; "$$python" -m venv $(@D); }
	tools/pip_install $(@D)/bin/python -q --upgrade pip
	sed -e 's/^bpy==.*/bpy==$(COMPAT_BPY_$*)/' -e 's/^numpy==.*/numpy==$(COMPAT_NUMPY_$*)/' requirements.txt \
		> $(@D)/requirements.txt
	tools/pip_install $(@D)/bin/python -q -r $(@D)/requirements.txt
	$(@D)/bin/python -m pip install -q --no-deps -e .
	@touch $@

comma := ,

# Every version is run even when one fails; the summary gives each result and wall time.
test-compat: $(foreach v,$(COMPAT_VERSIONS),.venv-blender-$(v)/.phrt-installed)
	@failed=""; summary=""; \
	for v in $(COMPAT_VERSIONS); do \
		echo "== Blender $$v: .venv-blender-$$v/bin/python -m pytest -q"; \
		start=$$(date +%s); \
		if .venv-blender-$$v/bin/python -m pytest -q; then result=passed; else result=FAILED; failed="$$failed $$v"; fi; \
		summary="$$summary\n  Blender $$v (bpy $$(.venv-blender-$$v/bin/python -c 'import importlib.metadata as m; print(m.version("bpy"))'), Python $$(.venv-blender-$$v/bin/python -c 'import platform; print(platform.python_version())')): $$result in $$(( $$(date +%s) - start )) s"; \
	done; \
	printf "== make test-compat$$summary\n"; \
	test -z "$$failed" || { echo "make test-compat: failed on Blender$$failed" >&2; exit 1; }

clean:
	rm -rf out dist wheels .pytest_cache
