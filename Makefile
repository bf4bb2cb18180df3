# Carto: the two commands.
#   make demo   set up .venv if needed, then run the whole chain on the embedded simulated scene
#   make test   set up .venv if needed, then ruff, the import contracts and the test suite
# Both build .venv from `python3` and requirements.lock and compile the numba kernels into their
# caches (tools/compile_kernels.py); they are quick when nothing changed.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.carto-installed
PACKAGES := carto-framework carto-cartosat1 carto-cartosat2 carto-ior
# Example third-party plugins (separate distributions on the public API), installed the same way.
EXAMPLES := carto-pleiades
TEST_PLUGINS := build/test-plugins
TEST_PLUGINS_STAMP := $(TEST_PLUGINS)/.carto-installed
KERNELS_STAMP := build/.kernels-compiled
PIP := $(BIN)/python -m pip --disable-pip-version-check
DEMO_OUT ?= demo-out

.PHONY: demo test fuzz lint format lock clean bytecode

demo: $(STAMP) bytecode $(KERNELS_STAMP)
	$(BIN)/carto demo --out $(DEMO_OUT)

test: lint $(TEST_PLUGINS_STAMP) bytecode $(KERNELS_STAMP)
	$(BIN)/python -m pytest -n 2 --dist worksteal

# Bytecode of the editable packages (only what changed): where PYTHONDONTWRITEBYTECODE is set,
# every `carto` process compiled them again (0.3-0.5 s of each command's start).
bytecode: $(STAMP)
	$(BIN)/python -m compileall -q packages/*/src examples/*/src > /dev/null

# The numba kernels compiled into their caches once the sources changed (set-up, like the
# bytecode; about 110 s on 2 cores, in two processes side by side): otherwise the first
# command, and every test worker at once, compiles them. Caches older than the sources go first
# (numba checks a kernel's cache against its own file only, not the modules it inlines).
$(KERNELS_STAMP): $(STAMP) $(shell find packages -name '*.py' -path '*/src/*' -not -path '*/__pycache__/*')
	$(MAKE) --no-print-directory bytecode
	$(BIN)/python tools/compile_kernels.py
	mkdir -p build && touch $@

# the fuzz tests with fresh random draws (make test draws the same fixed set every time)
fuzz: $(STAMP) $(TEST_PLUGINS_STAMP) bytecode $(KERNELS_STAMP)
	HYPOTHESIS_PROFILE=explore $(BIN)/python -m pytest -n 2 -m fuzz

# ruff, and the architecture contracts of .importlinter (layers, no cycles, no plugin names)
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports --no-cache
	$(BIN)/python tools/function_lengths.py

format: $(STAMP)
	$(BIN)/ruff check --fix .
	$(BIN)/ruff format .

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(BIN)/python requirements.lock $(foreach p,$(PACKAGES),packages/$(p)/pyproject.toml) \
		$(foreach e,$(EXAMPLES),examples/$(e)/pyproject.toml)
	$(PIP) install -q -r requirements.lock
	$(PIP) install -q --no-deps --no-build-isolation $(foreach p,$(PACKAGES),-e packages/$(p)) \
		$(foreach e,$(EXAMPLES),-e examples/$(e))
	$(PIP) check
	touch $@

# The third-party plugin fixtures: real distributions, installed where only the tests look
# (pytest puts build/test-plugins on sys.path), so the user's environment stays clean.
$(TEST_PLUGINS_STAMP): $(STAMP) $(shell find tests/plugins -type f -not -path '*/__pycache__/*' -not -path '*.egg-info*')
	rm -rf $(TEST_PLUGINS)
	$(PIP) install -q --no-deps --no-build-isolation --target $(TEST_PLUGINS) $(wildcard tests/plugins/*/)
	touch $@

lock:
	./tools/lock.sh

clean:
	rm -rf $(VENV) build .pytest_cache .ruff_cache
