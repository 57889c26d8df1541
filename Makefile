# focas-edge — every target sets itself up: a fresh clone needs only python3.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
RUN_STAMP := $(VENV)/.run-stamp

.PHONY: run test lint unit integration bench fuzz soak sim clean broker-check browser-check opcua-client-check venv \
        deb systemd-check arm64-check

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,dev,demo,bench,opcua]'
	@touch $(STAMP) $(RUN_STAMP)

# What running needs and nothing else (no test, lint or bench tools): the package and the embedded broker.
$(RUN_STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -e '.[demo,opcua]'
	@touch $(RUN_STAMP)

venv: $(STAMP)

## make run: a simulated fleet, a broker (system one, or an embedded one), the daemon and a compact live view
## (make run RAW=1, or ARGS=--raw: every message decoded). The demo's state lives in .state/ (untracked).
run: $(RUN_STAMP)
	$(PY) -m edge.cli.views.demo $(if $(RAW),--raw) $(ARGS)

## make test: lint, then the whole suite (unit + integration with a real mosquitto)
test: $(STAMP) broker-check browser-check opcua-client-check lint
	$(PY) -m pytest -q

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

unit: $(STAMP)
	$(PY) -m pytest -q tests/unit

integration: $(STAMP) broker-check browser-check opcua-client-check
	$(PY) -m pytest -q tests/integration

broker-check:
	@bash scripts/ensure-mosquitto.sh

browser-check:
	@bash scripts/ensure-chromium.sh

opcua-client-check:
	@bash scripts/ensure-node-opcua.sh

sim: $(STAMP)
	$(VENV)/bin/focas-edge sim --machines 3

bench: $(STAMP) broker-check
	$(PY) -m bench

## make soak: 20 simulated machines with random faults (SOAK_SECONDS, default 600); fails on loss or growth
soak: $(STAMP) broker-check
	$(PY) -m tests.soak

## make fuzz: the property tests with 20,000 examples each (minutes, not part of make test)
fuzz: $(STAMP)
	HYPOTHESIS_PROFILE=fuzz $(PY) -m pytest -q tests -k "property or fuzz"

clean:
	rm -rf $(VENV) .node .pytest_cache .mypy_cache .ruff_cache .hypothesis

## make deb: dist/focas-edge_<version>_<arch>.deb for this machine's architecture (dpkg-deb; docs/install.md)
deb:
	bash scripts/build-deb.sh

## make systemd-check: the .deb installed and run under a real systemd (nspawn, Debian 12); minutes, as root
systemd-check:
	bash scripts/systemd-check.sh

## make arm64-check: the arm64 .deb built and run in an arm64 Debian 12 under qemu-user-static; slow, as root
arm64-check:
	bash scripts/arm64-check.sh
