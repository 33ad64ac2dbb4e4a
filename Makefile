# snell_bench: every target does its own set-up on a fresh machine.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# Optional extras, comma-separated: test, gpu, render, metrics, depth (see README).
EXTRAS ?= test
# pytest-xdist workers for `make test` (whole test files per worker, so module fixtures are shared)
WORKERS ?= 2
# torch and torchvision must be a matched pair (a mismatched torchvision fails to import, and with
# it diffusers and open_clip). Override for another platform or CUDA version.
TORCH_SPEC ?= torch==2.14.1 torchvision==0.29.1
comma := ,
STAMP := $(VENV)/.installed-$(subst $(comma),-,$(EXTRAS))

.PHONY: setup setup-cycles demo test test-slow lint format bench clean docs docs-serve docs-results system-deps system-deps-slurm system-deps-browser

setup: $(STAMP)

# Open3D's wheel links libusb-1.0 at import time; Debian/Ubuntu machines need the system package.
# Mitsuba's LLVM variants (the reference renderer, ~3x faster than scalar_rgb) need an LLVM that
# Dr.Jit can load: Debian's libllvm19 (optional: without it the renderer falls back to scalar_rgb).
system-deps:
	@if [ "$$(uname -s)" = "Linux" ] && command -v ldconfig >/dev/null && ! ldconfig -p | grep -q 'libusb-1.0.so.0'; then \
	  echo "installing libusb-1.0-0 (needed by open3d)"; \
	  if command -v apt-get >/dev/null; then \
	    SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	    $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0; \
	  else echo "please install libusb-1.0 with your system package manager" >&2; exit 1; fi; \
	fi
	@if [ "$$(uname -s)" = "Linux" ] && command -v ldconfig >/dev/null && ! ldconfig -p | grep -q 'libLLVM.so.19'; then \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  if command -v apt-get >/dev/null && { apt-cache show libllvm19 >/dev/null 2>&1 || \
	      { $$SUDO apt-get update -qq && apt-cache show libllvm19 >/dev/null 2>&1; }; }; then \
	    echo "installing libllvm19 (Mitsuba's LLVM variants for the reference renderer)"; \
	    $$SUDO apt-get install -y -qq libllvm19 || echo "libllvm19 not installed: the reference renderer uses scalar_rgb"; \
	  else echo "no libllvm19 package here: the reference renderer uses scalar_rgb"; fi; \
	fi

# A single-node Slurm for the slow tests of tests/cluster/ (they start and stop their own daemons,
# with their own configuration, and skip when these binaries are missing): Debian/Ubuntu packages.
system-deps-slurm:
	@if ! command -v slurmctld >/dev/null && ! [ -x /usr/sbin/slurmctld ]; then \
	  echo "installing slurmctld slurmd munge slurm-client (a local Slurm for tests/cluster/)"; \
	  if command -v apt-get >/dev/null; then \
	    SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	    $$SUDO apt-get update -qq && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurmctld slurmd munge slurm-client; \
	  else echo "please install slurmctld, slurmd, munge and the Slurm client commands with your system package manager" >&2; exit 1; fi; \
	fi

# A headless browser for the slow test that opens the HTML report (tests/reports/test_html_browser.py):
# Debian's chromium and its WebDriver (the test skips, saying so, when they are missing).
system-deps-browser:
	@if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then \
	  echo "installing chromium chromium-driver (the HTML report's browser test)"; \
	  if command -v apt-get >/dev/null; then \
	    SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	    $$SUDO apt-get update -qq && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver; \
	  else echo "please install chromium and its chromedriver with your system package manager" >&2; exit 1; fi; \
	fi

$(STAMP): pyproject.toml | system-deps
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q $(TORCH_SPEC)
	$(PY) -m pip install -q -e ".[$(EXTRAS)]"
	touch $(STAMP)

# Blender Cycles as a Python module, for `reference.renderer=cycles` (the authors' reference render,
# recipe=authors): its own environment (bpy pins numpy 1.26; ~1.1 GB), run as a subprocess.
CYCLES_VENV ?= .venv-cycles
CYCLES_SPEC ?= bpy==4.5.15 trimesh scipy pillow
CYCLES_STAMP := $(CYCLES_VENV)/.installed-bpy-4.5.15

setup-cycles: $(CYCLES_STAMP)

$(CYCLES_STAMP):
	test -x $(CYCLES_VENV)/bin/python || $(PYTHON) -m venv $(CYCLES_VENV)
	$(CYCLES_VENV)/bin/python -m pip install -q --upgrade pip
	$(CYCLES_VENV)/bin/python -m pip install -q $(CYCLES_SPEC)
	$(CYCLES_VENV)/bin/python -c "import bpy; print('bpy', bpy.app.version_string)"
	touch $(CYCLES_STAMP)

demo: setup
	HF_HUB_OFFLINE=1 $(PY) -m snell_bench +experiment=smoke

test: setup
	HF_HUB_OFFLINE=1 $(PY) -m pytest -q -n $(WORKERS) --dist loadfile

# the documentation site (mkdocs-material, API pages by mkdocstrings) into site/, every warning an error
DOCS_STAMP := $(VENV)/.installed-docs
$(DOCS_STAMP): pyproject.toml | $(STAMP)
	$(PY) -m pip install -q -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	HF_HUB_OFFLINE=1 $(VENV)/bin/mkdocs build --strict

# the docs' result tables: reports/<experiment>/ tables -> docs/results/data/, and docs/assets/smoke.png
docs-results: setup
	HF_HUB_OFFLINE=1 $(PY) tools/docs_results.py

docs-serve: $(DOCS_STAMP)
	HF_HUB_OFFLINE=1 $(VENV)/bin/mkdocs serve

# the tests marked slow (end-to-end launchers, a real Slurm, the installed package, long sweeps)
test-slow: setup setup-cycles system-deps-slurm system-deps-browser
	HF_HUB_OFFLINE=1 $(PY) -m pytest -q -m slow

# import contracts (pyproject.toml [tool.importlinter]), import cycles between modules, and the
# sizes of modules (500 lines) and functions (80; tools/size_exceptions.txt may shrink, never grow):
# all run, and lint fails if any fails
lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	status=0; \
	$(VENV)/bin/lint-imports --no-cache || status=1; \
	$(PY) tools/check_imports.py snell_bench || status=1; \
	$(PY) tools/check_size.py snell_bench || status=1; \
	exit $$status

format: setup
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

bench: setup
	$(PY) benchmarks/bench_warps.py
	$(PY) benchmarks/bench_imaging.py
	$(PY) benchmarks/bench_sampler.py
	$(PY) benchmarks/bench_adaptive.py
	$(PY) benchmarks/bench_reference.py
	$(PY) benchmarks/bench_overlap.py

clean:
	rm -rf $(VENV) runs/ .pytest_cache
