# Urban Synthesis for QGIS: setup / demo / test / bench / package.
# Every target installs what it needs itself (QGIS from Debian, the venv, the example data),
# and each step is skipped when its stamp is newer than its inputs.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
PLUGIN_NAME := urban_synthesis
PLUGIN_LINK := build/plugins/$(PLUGIN_NAME)
QGIS_PROCESS := scripts/qgis-process

.PHONY: setup demo test test-fast bench package clean

setup: build/.system $(VENV)/.installed data/examples/.installed build/.plugin-enabled

build/.system: scripts/install_system.sh
	bash scripts/install_system.sh
	@mkdir -p build && touch $@

$(VENV)/.installed: requirements.txt scripts/install_venv.sh build/.system
	bash scripts/install_venv.sh $(VENV) requirements.txt
	@touch $@

$(VENV)/.bench-installed: requirements-bench.txt $(VENV)/.installed
	bash scripts/install_venv.sh $(VENV) requirements.txt requirements-bench.txt
	@touch $@

data/examples/.installed: scripts/fetch_example_data.py $(VENV)/.installed
	$(PY) scripts/fetch_example_data.py data/examples
	@touch $@

# QGIS loads plugins from QGIS_PLUGINPATH by folder name: link the checkout under a stable name
# and enable it once in the isolated profile used by scripts/qgis-process.
build/.plugin-enabled: metadata.txt $(VENV)/.installed
	@mkdir -p build/plugins
	ln -sfn "$(CURDIR)" $(PLUGIN_LINK)
	$(QGIS_PROCESS) plugins enable $(PLUGIN_NAME) > /dev/null
	@touch $@

demo: setup
	bash scripts/demo.sh

test: setup
	QT_QPA_PLATFORM=offscreen $(PY) -m pytest -q tests

bench: setup $(VENV)/.bench-installed
	QT_QPA_PLATFORM=offscreen $(PY) tests/benchmarks/bench_foundation.py
	QT_QPA_PLATFORM=offscreen $(PY) tests/benchmarks/bench_growth.py
	QT_QPA_PLATFORM=offscreen $(PY) tests/benchmarks/bench_parcels.py

package:
	@mkdir -p build/dist
	rm -f build/dist/$(PLUGIN_NAME).zip
	git archive --format=zip --prefix=$(PLUGIN_NAME)/ -o build/dist/$(PLUGIN_NAME).zip HEAD
	@echo build/dist/$(PLUGIN_NAME).zip

clean:
	rm -rf build out .pytest_cache
