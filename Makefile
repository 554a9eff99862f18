# One command per job; each creates .venv and installs what it needs.
PYTHON ?= python3
PACKAGES := formation shell body analysis agent leader netem recorder testbed
VENV := .venv
BIN := $(VENV)/bin
SCENARIO ?= paper
# Every file of the product's packages: a change to any of them reinstalls it (below).
PRODUCT_FILES := $(shell find $(PACKAGES) -name __pycache__ -prune -o -print)

.PHONY: run test bench lint typecheck architecture clean compose-test docs docs-check figures wifi-ns3-check

# What a run needs: a venv with the product's dependencies, no extra (make run stops here).
# setuptools and wheel (= [build-system] requires) let the product reinstall without build
# isolation: offline, in seconds. The old build/ goes first: setuptools would ship a deleted
# module again from it.
$(BIN)/.runtime: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip 'setuptools>=77' wheel
	rm -rf build
	$(BIN)/pip install --quiet .
	touch $@

# What the tests, the checks and the benchmarks need besides: the test tools, the ROS 2 bodies'
# packages (their tests run) and testkit/ (what the tests and benchmarks share), a development
# package beside the product: editable, as it is not the product under test.
$(BIN)/.installed: $(BIN)/.runtime testkit/pyproject.toml
	rm -rf build
	$(BIN)/pip install --quiet '.[test,ros2]'
	$(BIN)/pip install --quiet --no-deps --no-build-isolation -e testkit
	touch $@

# The product as a user installs it, not editable: the tests import it from site-packages,
# never from the checkout. Reinstalled whenever a file of the packages changes (added and
# removed files change their folder), so `make run` runs the code as edited.
$(BIN)/.product: $(BIN)/.runtime $(PRODUCT_FILES)
	rm -rf build
	$(BIN)/pip install --quiet --no-deps --force-reinstall --no-build-isolation .
	touch $@

# The example plug-in package (examples/formation-plugins-example), installed from its folder
# with no registry, as a user installs their own: the tests run it through every command.
EXAMPLE := examples/formation-plugins-example
EXAMPLE_FILES := $(shell find $(EXAMPLE) -name __pycache__ -prune -o -name build -prune -o -print)
$(BIN)/.example: $(BIN)/.installed $(BIN)/.product $(EXAMPLE_FILES)
	rm -rf $(EXAMPLE)/build
	$(BIN)/pip install --quiet --no-deps --force-reinstall --no-build-isolation ./$(EXAMPLE)
	touch $@

run: $(BIN)/.product
	PYTHONSAFEPATH=1 $(BIN)/formation run $(SCENARIO) --strategy all
	@echo "The formation command is $(BIN)/formation; 'source $(BIN)/activate' puts it on your PATH."

# PYTHONSAFEPATH=1: a `python -m agent` the tests start in the checkout would otherwise put
# the checkout first on its path and import the working tree (tests/unit/test_installed.py).
test: $(BIN)/.installed $(BIN)/.product $(BIN)/.example lint typecheck architecture
	PYTHONSAFEPATH=1 $(BIN)/pytest -q -p no:cacheprovider

lint: $(BIN)/.installed
	$(BIN)/ruff check $(PACKAGES) tests bench testkit examples
	$(BIN)/ruff format --check $(PACKAGES) tests bench testkit examples

typecheck: $(BIN)/.installed
	$(BIN)/mypy

architecture: $(BIN)/.installed
	$(BIN)/lint-imports

# The unchanged compose.yaml under each engine of ENGINES (podman-compose, Docker Compose v2),
# loopback only (deploy/compose.loopback.yaml), with the same checks, against a native run:
# deploy/<engine>.sh installs the engine and its compose if missing (Docker: a dockerd of the
# test's own, ended on exit), makes the base image when no registry serves it, builds the image
# (both cached in the engine's store). The tests fail, not skip, for an engine of ENGINES that
# cannot run (FORMATION_REQUIRE_CONTAINERS). The native run they compare with is the installed
# product, as for make test (.product: the checkout as edited). podman first: Docker loads the
# base image from podman's store.
ENGINES ?= podman docker
# podman's image has the example plug-ins too (podman-compose does not build): compose.plugins.yaml
# runs from it; Docker's `up --build` builds each file's own.
compose-test: $(BIN)/.installed $(BIN)/.product $(BIN)/.example
	set -e; trap 'deploy/docker.sh stop' EXIT; vars=; \
	export FORMATION_BUILD_FLAGS="--build-arg PLUGINS=./$(EXAMPLE) --build-arg EXTRAS=[ros2]"; \
	for engine in $(ENGINES); do \
	  deploy/$$engine.sh engine base build; vars="$$vars $$(deploy/$$engine.sh env)"; \
	done; \
	env PYTHONSAFEPATH=1 FORMATION_REQUIRE_CONTAINERS="$(ENGINES)" $$vars $(BIN)/pytest -q -p no:cacheprovider -m containers -s tests/containers

# The documentation site (mkdocs.yml) from docs/ into site/ (git-ignored): --strict makes a
# broken link or anchor, a stale API reference or a page left out of the nav fail the build
# (not --quiet: it drops the warnings before --strict counts them).
# The home page is README.md; the notebook shows the outputs it was saved with (make test runs it).
$(BIN)/.docs: $(BIN)/.product
	rm -rf build
	$(BIN)/pip install --quiet --no-build-isolation '.[docs]'
	touch $@

docs: $(BIN)/.docs
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

# The built home page in a real browser (Debian's chromium, installed if missing): a screenshot
# in site-check/ and the headline figure's <img> loaded (naturalWidth > 0).
docs-check: docs
	.ci/docs-check site site-check

# The README's headline figure, drawn from a simulation of the chapter's experiment.
figures: $(BIN)/.product
	MPLBACKEND=Agg $(BIN)/python examples/headline_figure.py docs/images/headline.png

bench: $(BIN)/.installed $(BIN)/.product $(BIN)/.example
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench

# The air model against ns-3 live (tests/integration/test_wifi_ns3.py): installs the optional
# extra [ns3] (about 520 MB) into the venv, then runs the one test that needs it.
wifi-ns3-check: $(BIN)/.installed $(BIN)/.product
	$(BIN)/pip install --quiet 'ns3>=3.44,<3.45'
	PYTHONSAFEPATH=1 $(BIN)/pytest -q -p no:cacheprovider tests/integration/test_wifi_ns3.py

clean:
	rm -rf $(VENV) runs build site site-check *.egg-info $(EXAMPLE)/build $(EXAMPLE)/*.egg-info
