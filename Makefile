# Urban Synthesis for QGIS: setup / demo / test / bench / package.
# Every target installs what it needs itself (QGIS from Debian, the venv, the example data),
# and each step is skipped when its stamp is newer than its inputs.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
PLUGIN_NAME := urban_synthesis
PLUGIN_LINK := build/plugins/$(PLUGIN_NAME)
QGIS_PROCESS := scripts/qgis-process

.PHONY: setup demo test test-fast sweep bench fidelity package desktop-check clean

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
	$(QGIS_PROCESS) plugins enable $(PLUGIN_NAME) > /dev/null || \
		$(QGIS_PROCESS) plugins 2>/dev/null | grep -qx '\* $(PLUGIN_NAME)'  # already enabled
	@touch $@

demo: setup
	bash scripts/demo.sh

# The whole suite under the machine's own BLAS kernel, then the engine tests (geometry,
# footprints, roads, parcels: no QGIS) again under a forced generic one, so that a result
# that depends on how a processor rounds a matrix product fails here, not on a user's
# machine (docs/ARCHITECTURE.md, "Floating point across processors"; tests/test_reproducible.py
# compares the two kernels' outputs).
ENGINE_TESTS := $(filter-out tests/test_alg_% tests/test_model_% tests/test_desktop.py \
	tests/test_package.py tests/test_provider.py tests/test_environment.py \
	tests/test_reproducible.py tests/test_distributed.py tests/test_bad_inputs.py \
	tests/test_cancel.py,$(wildcard tests/test_*.py))

test: setup
	URBANSYNTH_SWEEP=full QT_QPA_PLATFORM=offscreen $(PY) -m pytest -q tests
	OPENBLAS_CORETYPE=Prescott QT_QPA_PLATFORM=offscreen $(PY) -m pytest -q $(ENGINE_TESTS)

# Every case of the bad-input sweep (tests/bad_inputs.py: inputs generated from the example
# data, cases derived from each algorithm's parameters plus the findings of issue 22);
# `make test` runs every case too (about 2 min; pytest alone runs the core subset).
sweep: setup
	URBANSYNTH_SWEEP=full QT_QPA_PLATFORM=offscreen $(PY) -m pytest -q tests/test_bad_inputs.py

bench: setup $(VENV)/.bench-installed
	set -e; for b in tests/benchmarks/bench_*.py; do \
		echo "== $$b"; QT_QPA_PLATFORM=offscreen $(PY) $$b; done

# Road synthesis judged on towns it never saw (leave-one-town-out on Liechtenstein, plus
# Helsinki <-> Bubenec): tables in tests/benchmarks/results/fidelity.{json,md}, pictures in
# docs/fidelity_<town>.png; about 35 minutes on 2 cores (10 seeds for the example-based
# methods, 3 for the references growroads and splitdomain, most of the time theirs;
# FIDELITY_ARGS=--reference-seeds 1 saves about a third). FIDELITY_ARGS=--quick for three
# towns and one seed, written to the system's temporary folder (urbansynth-fidelity-quick/),
# not over the committed results.
fidelity: setup
	QT_QPA_PLATFORM=offscreen nice -n 10 $(PY) tests/benchmarks/bench_fidelity.py $(FIDELITY_ARGS)

# The plugin zip (top folder urban_synthesis/) holds what QGIS needs to run the plugin, taken
# from the committed tree (git archive HEAD): no tests, example data, dev scripts or README
# pictures. Uncommitted changes are not packaged (a warning says so).
PACKAGE_FILES := __init__.py metadata.txt README.md requirements.txt plugin processing_algorithms resources \
	$(shell git ls-files -- 'LICENSE*' 'COPYING*' 'ATTRIBUTION*' 2>/dev/null)
PACKAGE_ZIP := build/dist/$(PLUGIN_NAME).zip

package:
	@mkdir -p build/dist
	rm -f $(PACKAGE_ZIP)
	@test -z "$$(git status --porcelain -- $(PACKAGE_FILES))" || \
		echo "warning: the zip is built from HEAD; uncommitted plugin changes are not in it"
	git archive --format=zip --prefix=$(PLUGIN_NAME)/ -o $(PACKAGE_ZIP) HEAD -- $(PACKAGE_FILES)
	@echo "$(PACKAGE_ZIP) ($$(du -k $(PACKAGE_ZIP) | cut -f1) kB)"

# QGIS desktop under Xvfb with the plugin enabled in a fresh profile: provider, toolbox, dialogs,
# styled outputs, message log; screenshot in out/desktop.png.
desktop-check: setup
	$(PY) scripts/run_desktop_check.py --out out

clean:
	rm -rf build out .pytest_cache

# StreetGAN training (thesis ch. 4.2), CPU by default; torch lives in build/train-venv only.
# Rasterise the example networks, train the shipped generators, export ONNX + model cards.
TRAIN_PY := build/train-venv/bin/python
GAN_EPOCHS ?= 18
TOWNS_EPOCHS ?= 5
$(TRAIN_PY): requirements-train.txt
	/usr/bin/python3 -m venv build/train-venv
	$(TRAIN_PY) -m pip install -q -r requirements-train.txt

.PHONY: train-gan
train-gan: setup $(TRAIN_PY)
	$(PY) tools/streetgan/prepare.py build/streetgan
	nice -n 15 $(TRAIN_PY) tools/streetgan/train.py build/streetgan/helsinki.npz \
	  resources/models/streetgan_helsinki --epochs $(GAN_EPOCHS) --patch 161 --batch 4 --name streetgan_helsinki \
	  --title "Helsinki (real OSM roads)"
	nice -n 15 $(TRAIN_PY) tools/streetgan/train.py build/streetgan/grid.npz \
	  resources/models/streetgan_grid --epochs $(GAN_EPOCHS) --patch 161 --batch 4 --name streetgan_grid \
	  --title "Grid (growroads network)" --min-dead-end 120
	mv resources/models/streetgan_*_untrained.onnx build/streetgan/
	# Helsinki + the Liechtenstein towns but the held-out ones: a CPU fine-tune of the Helsinki
	# generator (see resources/models/streetgan_towns.json for the run that is shipped)
	nice -n 15 $(TRAIN_PY) tools/streetgan/train.py build/streetgan/helsinki.npz build/streetgan/li_*.npz \
	  resources/models/streetgan_towns --init-onnx resources/models/streetgan_helsinki.onnx \
	  --epochs $(TOWNS_EPOCHS) --patch 161 --batch 8 --lr 0.0002 --name streetgan_towns --no-untrained \
	  --title "Helsinki and eight Liechtenstein towns (real OSM roads)" --held-out Triesen,Eschen,Mauren
	QT_QPA_PLATFORM=offscreen $(PY) tests/benchmarks/bench_gan.py --cards

# The shipped towns model: the thesis's recipe (321 px patches, batch 64) from scratch on a GPU,
# stopped after 7.5 minutes (an H200: 78 epochs; resources/models/streetgan_towns.json). Without a
# GPU, train-gan's CPU fine-tune above is the fallback
.PHONY: train-gan-gpu
train-gan-gpu: setup $(TRAIN_PY)
	$(PY) tools/streetgan/prepare.py build/streetgan
	$(TRAIN_PY) tools/streetgan/train.py build/streetgan/helsinki.npz build/streetgan/li_*.npz \
	  resources/models/streetgan_towns --device cuda --patch 321 --batch 64 --filters 16 \
	  --epochs 400 --minutes 7.5 --name streetgan_towns --no-untrained --erosions 1 --dilations 1 \
	  --held-out Triesen,Eschen,Mauren --title "Helsinki and eight Liechtenstein towns (real OSM roads)"
	QT_QPA_PLATFORM=offscreen $(PY) tests/benchmarks/bench_gan.py --cards
