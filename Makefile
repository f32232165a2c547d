# taichi_cloth: every target sets up .venv from requirements*.txt on first use; setup also makes
# sure a Vulkan driver is there for headless rendering (scripts/ensure-vulkan.sh).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SCENE ?= hula
ARGS ?=
STAMP := $(VENV)/.installed

.PHONY: setup simulate render video compare bench test clean

$(STAMP): requirements.txt requirements-test.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt -r requirements-test.txt
	touch $(STAMP)

setup: $(STAMP)
	@sh scripts/ensure-vulkan.sh

simulate: setup
	$(PY) -m taichi_cloth simulate $(SCENE) $(ARGS)

render: setup
	$(PY) -m taichi_cloth render $(SCENE) $(ARGS)

video: setup
	$(PY) -m taichi_cloth render $(SCENE) --video mp4 $(ARGS)

compare: setup
	$(PY) -m taichi_cloth compare $(SCENE) $(ARGS)

bench: setup
	$(PY) -m taichi_cloth bench $(ARGS)

test: setup
	$(PY) -m pytest -q -n 2 tests

clean:
	find output -mindepth 1 ! -name .gitkeep -exec rm -rf {} +
