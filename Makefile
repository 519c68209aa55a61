# The README's commands: `make setup` installs everything into .venv (and .venv-numpy2, numpy 2
# alone for tests/test_numpy2.py), `make test` lints and runs the whole suite, `make demo` runs
# the demo (archhead_blender/demo.py), `make extension` builds the installable zip for this
# platform into dist/ (scripts/build_extension.py), `make test-ui` runs the UI suite in the real
# Blender binaries 4.3.2 (Debian trixie) and 5.2.2 (sid) (tests/ui; needs root and Debian's
# archive the first time, to build each binary's env: scripts/blender_env.py),
# `make ui-screenshots` copies its screenshots into docs/.
PY ?= python3.11
# numpy 2.5 needs Python 3.12 or later (Blender 5.x brings 3.13): the first found, else $(PY)
# and numpy 2.4
PY_NUMPY2 ?= $(firstword $(wildcard $(HOME)/.pyenv/versions/3.13*/bin/python3 \
	$(HOME)/.pyenv/versions/3.12*/bin/python3 /usr/bin/python3.13 /usr/bin/python3.12) $(PY))
VENV := .venv
BIN := $(VENV)/bin

.PHONY: setup test test-ui ui-screenshots demo extension format
setup:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	$(BIN)/pip install -e '.[dev]'
	$(BIN)/pip install --no-deps mediapipe==0.10.21  # the last wheel with its models inside
	$(BIN)/python -c "from archhead_addon.track.real_subject import fetch_media, fetch_webcam; fetch_media(); fetch_webcam()"
	$(BIN)/python -m archhead_addon.splat.build
	$(PY_NUMPY2) -m venv .venv-numpy2  # numpy 2 alone: the Blender-side decode under Blender's numpy (tests/test_numpy2.py)
	.venv-numpy2/bin/pip install --quiet "numpy>=2.4,<2.6"  # the newest this Python takes

test:
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest

# The UI suite once per binary, oldest first: trixie (Blender 4.3.2; out/ui, what
# ui-screenshots copies) then sid (Blender 5.2.2; out/ui-sid). Each env is built once and
# cached (scripts/blender_env.py); both runs go ahead, and a failure names its binary.
test-ui:
	@status=0; for suite in trixie sid; do \
		echo "== UI suite in $$suite's Blender =="; \
		ARCHHEAD_BLENDER_SUITE=$$suite $(BIN)/python -m pytest --ui -m ui tests/ui \
			|| { echo "== UI suite FAILED in $$suite's Blender =="; status=1; }; \
	done; exit $$status

ui-screenshots: test-ui
	$(BIN)/python tests/ui/docs_screenshots.py

demo:
	$(BIN)/python -m archhead_addon demo --out out/demo

extension:
	$(BIN)/python scripts/build_extension.py --out dist

format:
	$(BIN)/ruff format .
