# geofuse: the two commands of a fresh machine are `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
APP    := $(VENV)/.installed-app
TEST   := $(VENV)/.installed-test

.PHONY: demo test setup bench clean lint

$(APP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $(APP)

$(TEST): $(APP)
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(TEST)

setup: $(TEST)

# The viewer where there is a display to open it on; a still of the sample where there is none.
# Whether there is one is asked of the environment, not of the viewer's exit status: a viewer
# that fails on a display (a crash, OpenGL below 4.0) says why and `make demo` fails with it.
demo: $(APP)
	@if [ -n "$$DISPLAY$$WAYLAND_DISPLAY" ]; then \
		$(PY) -m app view; \
	else \
		echo "no display (DISPLAY and WAYLAND_DISPLAY are unset): rendering the sample to out/demo.png instead"; \
		$(PY) -m app demo; \
	fi

# Two workers, a test file each at a time (a module's fixtures built once): CI has two cores.
test: $(TEST)
	$(PY) -m pytest -q -n 2 --dist loadfile

lint: $(TEST)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

bench: $(TEST)
	$(PY) -m app bench render

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
