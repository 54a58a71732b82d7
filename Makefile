# Two commands for a newcomer: `make demo` and `make test`. Both bootstrap a fresh machine.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.bootstrap-$(shell cat pyproject.toml Makefile | sha256sum | cut -c1-12)
PYTEST_ARGS ?=
# node-opcua drives the OPC UA gateway in its tests (an independent stack); npm puts it in .node/.
NODE_DIR := .node
NODE_OPCUA := 2.186.4
NODE_STAMP := $(NODE_DIR)/.installed-node-opcua-client-$(NODE_OPCUA)

.PHONY: demo test test-all bootstrap system-deps node-deps lint typecheck clean

demo: $(STAMP)
	$(VENV)/bin/cellctl demo

# CI runs `make test`: lint and the type check first (seconds when mypy's cache is warm), then the tests.
test: $(STAMP) node-deps lint typecheck
	$(PY) -m pytest -q $(PYTEST_ARGS)

test-all: $(STAMP) node-deps
	$(PY) -m pytest -q -m "" $(PYTEST_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check cellctl tests tools

# mypy (settings in pyproject.toml, cache in .venv/): strict packages clean, the rest within .ci/mypy_baseline.json.
typecheck: $(STAMP)
	$(PY) .ci/mypy_gate.py

bootstrap: $(STAMP)

# open3d's wheel links libusb at import time; Debian does not ship it by default.
system-deps:
	@if ! ldconfig -p | grep -q libusb-1.0.so.0; then \
	  echo "installing libusb-1.0-0 (needed by open3d)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0; \
	fi
	@# The HMI's browser tests drive Debian's headless Chromium (no browser download).
	@if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then \
	  echo "installing chromium and chromium-driver (HMI browser tests)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver; \
	fi

# Quick when present; without npm the node-opcua tests skip (they say why).
node-deps:
	@if ! command -v npm >/dev/null; then \
	  echo "npm not found: the node-opcua gateway tests will be skipped"; \
	elif [ ! -f $(NODE_STAMP) ]; then \
	  echo "installing node-opcua-client@$(NODE_OPCUA) into $(NODE_DIR)/ (gateway tests)"; \
	  npm install --prefix $(NODE_DIR) --no-audit --no-fund --silent node-opcua-client@$(NODE_OPCUA) && touch $(NODE_STAMP); \
	fi

$(STAMP): pyproject.toml Makefile | system-deps
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# The local CPU wheel first, so nothing pulls a multi-GB CUDA build.
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'
	@rm -f $(VENV)/.bootstrap-*
	@touch $@

clean:
	rm -rf $(VENV) $(NODE_DIR) build *.egg-info
