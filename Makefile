# taichi_cloth: every target sets up .venv from requirements*.txt on first use; setup also makes
# sure a Vulkan driver is there for headless rendering and a virtual display for the viewer's
# test (scripts/ensure-system.sh).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SCENE ?= hula
ARGS ?=
STAMP := $(VENV)/.installed

.PHONY: setup simulate render video compare bench test check-blender clean

$(STAMP): requirements.txt requirements-test.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt -r requirements-test.txt
	touch $(STAMP)

setup: $(STAMP)
	@sh scripts/ensure-system.sh

simulate: setup
	$(PY) -m taichi_cloth simulate $(SCENE) $(ARGS)

render: setup
	$(PY) -m taichi_cloth render $(SCENE) $(ARGS)

# the last run of the scene drawn again from its cache when there is one (and no ARGS), else a run
video: setup
	if [ -z "$(ARGS)" ] && [ -f output/$(SCENE)/cache/scene.json ]; then \
		$(PY) -m taichi_cloth render --from-cache output/$(SCENE) --video mp4; \
	else \
		$(PY) -m taichi_cloth render $(SCENE) --video mp4 $(ARGS); \
	fi

compare: setup
	$(PY) -m taichi_cloth compare $(SCENE) $(ARGS)

bench: setup
	$(PY) -m taichi_cloth bench $(ARGS)

test: setup
	$(PY) -m pytest -q -n 2 tests

# Blender (pip's bpy, Blender 5.0 as a Python module, ~350 MB) imports the USD stage and the OBJ +
# PC2 point cache of a short hula run and reads the animated points back (scripts/check-blender.py),
# then counts the crossings of a second of twirl's PLY meshes (scripts/check-crossings-blender.py)
check-blender: setup
	test -x .venv-blender/bin/python || $(PYTHON) -m venv .venv-blender
	.venv-blender/bin/python -m pip install --quiet bpy==5.0.1 numpy==1.26.4
	$(PY) -m taichi_cloth simulate hula --frames 6 --set "cloth.resolution=[32,14]" --quiet \
		--meshes obj,usd,pc2 --out output/check-blender
	.venv-blender/bin/python scripts/check-blender.py output/check-blender/meshes
	$(PY) -m taichi_cloth simulate twirl --frames 30 --quiet --meshes ply --out output/check-crossings
	.venv-blender/bin/python scripts/check-crossings-blender.py output/check-crossings

clean:
	find output -mindepth 1 ! -name .gitkeep -exec rm -rf {} +
