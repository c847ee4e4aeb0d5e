# Two commands: `make run [PORT=N]` and `make test`. Both create .venv when missing.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
PORT ?= $(or $(ASSET_PREVIEW_PORT),8000)

.PHONY: run test lint install check-egl clean

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import venv, ensurepip' 2>/dev/null || { echo "error: Python venv support missing; install it with: apt-get install -y python3-venv"; exit 1; }
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test,reference]'
	$(PY) -m renderer.methods.trace_kernel
	$(PY) -m pipeline.interior.vectors
	@touch $(STAMP)

install: $(STAMP)

# Headless OpenGL needs Mesa's EGL and DRI drivers (llvmpipe on a CPU machine).
check-egl: $(STAMP)
	@$(PY) -c "import moderngl; moderngl.create_standalone_context(backend='egl', require=330).release()" 2>/dev/null || { \
	  echo "error: headless OpenGL (EGL) is not available."; \
	  echo "  install Mesa's EGL and DRI drivers: apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri libgles2"; \
	  exit 1; }

run: check-egl
	$(VENV)/bin/asset-preview serve --host 127.0.0.1 --port $(PORT)

# ruff (pyflakes, pycodestyle, bugbear, import order) and mypy, configured in pyproject.toml
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

test: check-egl lint
	$(PY) -m renderer.methods.trace_kernel
	$(PY) -m pipeline.interior.vectors
	$(PY) -m pytest -q

clean:
	rm -rf $(VENV) .cache build *.egg-info
