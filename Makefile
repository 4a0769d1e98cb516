# The two commands of the README: `make demo` and `make test`. Both set up .venv themselves.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-serial test-nightly bench lint format clean system-deps

$(STAMP): setup.py
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[train,dev]"
	touch $(STAMP)

venv: $(STAMP)

# Debian packages the renderer needs (EGL + Mesa llvmpipe); skipped when not root or without apt.
system-deps:
	@bash .ci/system-deps.sh

demo: $(STAMP) system-deps
	$(BIN)/tween fill examples/sh010_walk.usda --render --out-dir out/demo

# pytest-xdist (in [dev]): one process per core, each taking whole files, so a file's module
# fixtures (a Redis farm, its workers) are set up once. Every farm test points the process's
# Celery app at its own farm with tests/redis_server.py:configure_app, which drops what an
# earlier file cached (result backend, pools); `make test-serial` runs it all in one process.
test: $(STAMP) system-deps
	$(BIN)/python -m pytest -q -n auto --dist loadfile tests

test-serial: $(STAMP) system-deps
	$(BIN)/python -m pytest -q tests

# The generated bad-input tests with ten times the examples per command, and every shipped clip
# read (about 7 minutes).
test-nightly: $(STAMP) system-deps
	TWEEN_HYPOTHESIS_EXAMPLES=2000 TWEEN_ALL_DATA=1 $(BIN)/python -m pytest -q tests/test_bad_input_generated.py tests/motion/test_bvh.py

bench: $(STAMP)
	$(BIN)/tween bench --methods zero,interp --force

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

clean:
	rm -rf $(VENV) .cache .pytest_cache
