# Two commands: `make run [PORT=N]` and `make test`. Both create .venv when missing.
# `make run` installs what the service needs (`make install`); `make test` adds the test and
# reference extras (`make install-test`). `make image` builds the container (docker/build.sh).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
PORT ?= $(or $(ASSET_PREVIEW_PORT),8000)

.PHONY: run test lint install install-test check-egl image clean brdf-lut studio-env

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import venv, ensurepip' 2>/dev/null || { echo "error: Python venv support missing; install it with: apt-get install -y python3-venv"; exit 1; }
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e .
	$(PY) -m renderer.methods.trace_kernel
	$(PY) -m pipeline.interior.vectors
	@touch $(STAMP)

$(TEST_STAMP): $(STAMP)
	$(PY) -m pip install -q -e '.[test,reference]'
	@touch $(TEST_STAMP)

install: $(STAMP)

install-test: $(TEST_STAMP)

# Headless OpenGL needs Mesa's EGL and DRI drivers (llvmpipe on a CPU machine).
check-egl: $(STAMP)
	@$(PY) -c "import moderngl; moderngl.create_standalone_context(backend='egl', require=330).release()" 2>/dev/null || { \
	  echo "error: headless OpenGL (EGL) is not available."; \
	  echo "  install Mesa's EGL and DRI drivers: apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri libgles2"; \
	  exit 1; }

run: check-egl
	$(VENV)/bin/asset-preview serve --host 127.0.0.1 --port $(PORT)

# ruff (pyflakes, pycodestyle, bugbear, import order) and mypy, configured in pyproject.toml
lint: $(TEST_STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

test: check-egl lint $(TEST_STAMP)
	$(PY) -m renderer.methods.trace_kernel
	$(PY) -m pipeline.interior.vectors
	$(PY) -m pytest -q

# The split-sum BRDF LUT shipped in pipeline/data/ (it depends only on the prefilter's
# constants and shader; tests/test_environment.py fails when it no longer matches them)
brdf-lut: $(STAMP)
	$(PY) -m pipeline.environment.prefilter

# after the LUT: the studio's shipped bakes hold it (and every constant of the bake key)
studio-env: $(STAMP)
	$(PY) -m pipeline.environment.shipped

# BASE=debootstrap to build from a Debian base made here; SMOKE=1 to run and probe it
image:
	docker/build.sh

clean:
	rm -rf $(VENV) .cache build *.egg-info
