# The two README commands: `make demo` and `make test`. Both set everything up first
# (venv, pinned pip install, colcon build); setup is idempotent and fast when done.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
STAMP := $(VENV)/.requirements-installed
ENV := source scripts/env.sh

.PHONY: setup build demo test bench evaluate clean

setup: build

$(STAMP): requirements.txt
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --disable-pip-version-check -q -r requirements.txt
	touch $(STAMP)

build: $(STAMP)
	@$(ENV) && colcon --log-base log build --merge-install --base-paths src \
		--event-handlers console_stderr- summary- status- terminal_title- 2>&1 | tail -n 20

demo: setup
	@$(ENV) && bash scripts/demo.sh

test: setup
	@$(ENV) && bash scripts/run_tests.sh

bench: setup
	@$(ENV) && bash scripts/bench.sh

evaluate: setup
	@$(ENV) && bash scripts/evaluate.sh

clean:
	rm -rf build install log out
