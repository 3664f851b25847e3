# Two commands set everything up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The optional-dependency extras make install puts in the virtualenv (pyproject.toml).
EXTRAS := test,docs,lint

.PHONY: install demo sensitivity test test-slow bench docs lint clean

install: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[$(EXTRAS)]'
	touch $(STAMP)

# The main job: a UAV survey over a generated Greenland outlet glacier, its 3-D view, and its
# coverage (a CF grid of 40 m cells, one row per survey line, and its map).
demo: install
	$(BIN)/chirplidar run missions/greenland_uav.toml --out outputs/greenland_uav.nc --overwrite
	$(BIN)/chirplidar view outputs/greenland_uav.nc --png outputs/greenland_uav.png
	$(BIN)/chirplidar coverage outputs/greenland_uav.nc --cell-m 40 --overwrite \
	    --out outputs/greenland_uav_coverage.nc --png outputs/greenland_uav_coverage.png

# Thesis Fig. 5.7 (sensitivity of the three receivers) into outputs/fig5_7_sensitivity.{png,csv}.
sensitivity: install
	$(BIN)/chirplidar sensitivity --out outputs

test: install
	$(BIN)/python -m pytest -q

# The slow validations (e.g. baseband range RMS within 10 % of rf with 400 shots per point).
test-slow: install
	$(BIN)/python -m pytest -q -m slow

bench: install
	$(BIN)/chirplidar bench --what startup
	$(BIN)/chirplidar bench --what shot
	$(BIN)/chirplidar bench --what raycast
	$(BIN)/chirplidar bench --what tiers
	$(BIN)/chirplidar bench --what survey
	$(BIN)/chirplidar bench --what scale --repeats 21
	$(BIN)/chirplidar bench --what scale --repeats 5 --mission missions/greenland_uav_1h.toml \
	    --set survey.stop_s=800
	$(BIN)/chirplidar bench --what run
	$(BIN)/chirplidar bench --what campaign
	$(BIN)/chirplidar bench --what accuracy --out outputs
	$(BIN)/chirplidar bench --what coverage

# The documentation site into site/ (mkdocs.yml); warnings are errors.
docs: install
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

# Lint: ruff everywhere, ruff format and mypy on the physics kernels and the tiers (the lists in
# pyproject.toml and KERNEL_PATHS), the import layers (lint-imports, on this checkout's src) and
# the module-level viz imports lint-imports cannot see (tests/test_layers.py).
KERNEL_PATHS := src/chirplidar/units.py src/chirplidar/_checks.py src/chirplidar/_threads.py \
	src/chirplidar/doppler.py src/chirplidar/optics src/chirplidar/atmosphere src/chirplidar/target \
	src/chirplidar/geometry src/chirplidar/processing src/chirplidar/receiver \
	src/chirplidar/transmitter src/chirplidar/waveform src/chirplidar/streams.py \
	src/chirplidar/lazy.py src/chirplidar/mission_files.py \
	src/chirplidar/tiers tests/test_layers.py

lint: install
	$(BIN)/ruff check src tests
	$(BIN)/ruff format --check $(KERNEL_PATHS)
	$(BIN)/mypy
	PYTHONPATH=src $(BIN)/lint-imports
	$(BIN)/python -m pytest -q -p no:cacheprovider tests/test_layers.py

clean:
	rm -rf $(VENV) build site src/*.egg-info
