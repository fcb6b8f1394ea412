# Two entry points (see README): `make demo` and `make test`.
# Both create .venv from requirements.txt on first use (and again when it changes).
PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench build clean-venv
.DEFAULT_GOAL := demo

$(STAMP): requirements.txt
	test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --quiet --upgrade pip
	$(VPY) -m pip install --quiet -r requirements.txt
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VPY) scratch_addon/cli.py --preset demo --out renders/demo.png

test: $(STAMP)
	$(VPY) -m pytest -q -p no:cacheprovider tests

bench: $(STAMP)
	$(VPY) -m bench --list

build: $(STAMP)
	$(VPY) -m scratch_addon.build_ext dist

clean-venv:
	rm -rf $(VENV)
