# One command per job; each creates .venv and installs what it needs.
PYTHON ?= python3
PACKAGES := formation agent leader netem recorder testbed
VENV := .venv
BIN := $(VENV)/bin
SCENARIO ?= scenarios/paper.toml

.PHONY: run test bench lint typecheck architecture clean compose-test

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $@

run: $(BIN)/.installed
	$(BIN)/formation run $(SCENARIO) --strategy all

test: $(BIN)/.installed lint typecheck architecture
	$(BIN)/pytest -q -p no:cacheprovider

lint: $(BIN)/.installed
	$(BIN)/ruff check $(PACKAGES) tests bench
	$(BIN)/ruff format --check $(PACKAGES) tests bench

typecheck: $(BIN)/.installed
	$(BIN)/mypy

architecture: $(BIN)/.installed
	$(BIN)/lint-imports

# The unchanged compose.yaml under podman-compose, loopback only (deploy/compose.loopback.yaml),
# checked against a native run: installs podman and podman-compose if missing, makes the base
# image when no registry serves it, builds the image (both cached in podman's store). The tests
# fail, not skip, without podman-compose (FORMATION_REQUIRE_CONTAINERS=1).
compose-test: $(BIN)/.installed
	deploy/podman.sh engine base build
	env FORMATION_REQUIRE_CONTAINERS=1 $$(deploy/podman.sh env) $(BIN)/pytest -q -p no:cacheprovider -m containers -s tests/containers

bench: $(BIN)/.installed
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench

clean:
	rm -rf $(VENV) runs build *.egg-info
