# The two commands of the README: `make setup` installs everything into .venv,
# `make test` lints and runs the whole suite. `make demo` runs the demo
# (operators/script_demo.py: subject, short training, import, LOD driver, clip, .blend).
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin

.PHONY: setup test demo
setup:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	$(BIN)/pip install -e '.[dev]'
	$(BIN)/pip install --no-deps mediapipe==0.10.21  # the last wheel with its models inside
	$(BIN)/python -c "from archhead_addon.track.real_subject import fetch_media; fetch_media()"
	$(BIN)/python -m archhead_addon.splat.build

test:
	$(BIN)/ruff check .
	$(BIN)/python -m pytest

demo:
	$(BIN)/python -m archhead_addon demo --out out/demo
