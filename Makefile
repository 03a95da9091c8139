# The two commands a newcomer runs (README): `make demo` and `make test`.
# Both install what is missing first (scripts/setup.sh is idempotent and fast when done).
.PHONY: setup demo test lint format

VENV := .venv
PY := $(VENV)/bin/python
ARGS ?=

setup:
	@bash scripts/setup.sh

demo: setup
	@$(VENV)/bin/stereo_tracking_demo $(ARGS)

test: setup
	@$(PY) -m pytest $(ARGS)

lint: setup
	@$(VENV)/bin/ruff check . && $(VENV)/bin/ruff format --check .

format: setup
	@$(VENV)/bin/ruff format . && $(VENV)/bin/ruff check --fix .
