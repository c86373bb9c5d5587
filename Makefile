# Set-up and everyday targets. `make run` and `make test` work on a fresh machine with Python >= 3.11:
# they create .venv, install nrtraffic with SUMO from PyPI, and run. `make docs` builds the user's
# guide (docs/, mkdocs.yml) into site/.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
SCENARIO ?= sumo_scenarios/cross4/scenario.toml
OUT    ?= runs

.PHONY: install run test docs paper bench studies nets golden docs-figures clean clean-cache

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/nrtraffic run $(SCENARIO) --out $(OUT)/default

test: $(STAMP)
	$(BIN)/python -m pytest

# the user's guide: MkDocs (Material) into site/; --strict fails on a broken link, anchor or page
DOCS_STAMP := $(VENV)/.installed-docs
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -m pip install --quiet -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

paper: $(STAMP)
	$(BIN)/nrtraffic paper all --out $(OUT)/paper

bench: $(STAMP)
	$(BIN)/nrtraffic bench

# every study committed under docs/, run again (about 10 run-hours; runners/studies.py, --list shows them)
studies: $(STAMP)
	$(BIN)/python -m runners.studies

nets: $(STAMP)
	$(BIN)/python sumo_scenarios/paper_curved/generate.py
	$(BIN)/python sumo_scenarios/paper_cbf/generate.py
	$(BIN)/python sumo_scenarios/generate_junctions.py
	$(BIN)/python sumo_scenarios/grid4/generate.py
	$(BIN)/python sumo_scenarios/grid4/generate.py --no-network --rate 300 --routes demand_high.rou.xml

# the recorded run that the tests replay (tests/test_replay.py); regenerate it, and commit it, only
# when a deliberate change alters results. Recorded and replayed with numba's portable CPU target.
GOLDEN := tests/golden/cross4
golden: $(STAMP)
	rm -rf $(GOLDEN)
	NUMBA_CPU_NAME=generic $(BIN)/nrtraffic run sumo_scenarios/cross4/scenario.toml --seed 7 --duration 75 \
	    --set demand.end_s=25 --set demand.rate_veh_h=600 --set outputs.trajectory_interval_s=0.5 --set outputs.warmup_s=0 --out $(GOLDEN) --no-progress
	rm -f $(addprefix $(GOLDEN)/,movements.png delays.png queues.png time_space.png report.html manifest.json)

# the documentation's screenshots of reports (docs/report_cross4_counts.png), from fresh runs into
# runs/docs; needs Chromium (runners/docs_figures.py lists them)
docs-figures: $(STAMP)
	$(BIN)/python -m runners.docs_figures

# numba's on-disk cache does not notice edits in the modules a kernel calls: clear it after editing
clean-cache:
	find nrtraffic -name '*.nbi' -delete -o -name '*.nbc' -delete

clean: clean-cache
	rm -rf $(VENV) $(OUT) .pytest_cache site
