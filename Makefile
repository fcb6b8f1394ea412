# Two entry points (see README): `make demo` and `make test`.
# Both create .venv from requirements.txt on first use (and again when it changes).
PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench build build-dev venv clean-venv
.DEFAULT_GOAL := demo

$(STAMP): requirements.txt
	test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --quiet --upgrade pip
	$(VPY) -m pip install --quiet -r requirements.txt
	touch $(STAMP)

venv: $(STAMP)

# The README image: the demo preset (Fig. 1d's layers) on a floor receding from the camera under one small point
# light; 96 spp (about 32 s wall on this 2-core machine), OSL: lit scratches streak radially around the highlight, one by one near, a sheen far away.
demo: $(STAMP)
	$(VPY) scratch_addon/cli.py --preset demo --layout highlights --out docs/img/demo.png --samples 96 --res 640 480

# Two pytest-xdist workers (one test file each at a time) on single-threaded OpenBLAS: with two workers the
# BLAS threads only spin against each other (a bi-scale test file: user + sys CPU 30.1 -> 27.3 s, sys 8.7 -> 3.4 s).
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(VPY) -m pytest -q -p no:cacheprovider -n 2 --dist loadfile --durations=15 tests

bench: $(STAMP)
	$(VPY) -m bench --list

# Blender's own extension tool, shipped inside the bpy wheel.
BLENDER_EXT = $(VPY) -c "import importlib.util as u, pathlib as p, runpy, sys; \
	cli = sorted(p.Path(u.find_spec('bpy').origin).parent.glob('*/scripts/addons_core/bl_pkg/cli/blender_ext.py'))[-1]; \
	sys.argv = ['blender_ext.py'] + sys.argv[1:]; runpy.run_path(str(cli), run_name='__main__')"

# One zip per platform (linux-x64, windows-x64, macos-arm64, macos-x64) with the `# bundled` pins of
# requirements.txt as wheels (cached in wheels/); each is validated and checked; prints name and size.
build: $(STAMP)
	$(VPY) build.py --output-dir dist

# The plain zip without wheels (for a Blender whose Python already has scipy and OpenEXR).
build-dev: $(STAMP)
	mkdir -p dist
	$(BLENDER_EXT) build --source-dir . --output-dir dist
	$(BLENDER_EXT) validate dist/scratch_addon-$$(sed -n 's/^version = "\(.*\)"/\1/p' blender_manifest.toml).zip

clean-venv:
	rm -rf $(VENV)
