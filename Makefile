# fieldloc: `make demo` and `make test` work on a fresh clone with nothing but Python 3.10+.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
FL     := $(BIN)/fieldloc -q
# the steps that can run for minutes (bench, extract, localize, a template grid, build-templates)
# keep their progress (bars on a terminal, bench's row names) and their closing summary line
FLP    := $(BIN)/fieldloc
STAMP  := $(VENV)/.installed

OUT     ?= build
FIELD   ?= msl-2015
FRAMES  ?= 100
SEED    ?= 1
METHOD  ?= lut
HEADING ?= imu
SMOOTH  ?=
DATA    ?= $(OUT)/demo-omni
MAP     := $(OUT)/maps/$(notdir $(basename $(FIELD))).map.h5
FIELD_FILE := $(or $(wildcard maps/$(FIELD).yaml),$(wildcard $(FIELD)))
# --heading is an option of lut only
HEADING_OPT := $(if $(filter lut,$(METHOD)),--heading $(HEADING))
# SMOOTH=1: `localize --smooth`, decided with the whole recording (docs/smoothing.md)
SMOOTH_OPT := $(if $(SMOOTH),--smooth)
# a run's folder: $(call run_dir,DATA,SMOOTH) (the demo names both of its runs by it)
run_dir = $(1)/runs/$(METHOD)$(if $(filter lut,$(METHOD)),-$(HEADING))$(if $(2),-smooth)
RUN     := $(call run_dir,$(DATA),$(SMOOTH))

.PHONY: install warmup test lint docs demo templates-demo bench bench-readme compare pipeline \
	run-report clean

install: $(STAMP)

# pip relays setuptools' note that an editable install of a flat layout puts the project folder
# on sys.path ("Editable installation ... folders with the same name as your package"): that is
# this layout on purpose, so that one note is filtered; every other warning shows.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	PYTHONWARNINGS="ignore:Editable installation" $(BIN)/python -m pip install --quiet -e '.[dev,docs]'
	$(BIN)/python -m compileall -q stages fieldloc_cli
	$(BIN)/python -m stages.pipelines.warmup
	touch $(STAMP)

# numba's machine code of every kernel, in __pycache__ beside the sources (install runs it; run
# it again after changing a kernel, or the first command after the change compiles it)
warmup: $(STAMP)
	$(BIN)/python -m stages.pipelines.warmup

# the suite on up to TEST_JOBS worker processes (pytest-xdist; "auto": one per core, at most
# 4, as each worker builds the session's shared renders itself; TEST_JOBS=0 runs in one process)
TEST_JOBS ?= auto
test: $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_JOBS) --maxprocesses 4

lint: $(STAMP)
	$(BIN)/ruff check .

# the documentation site (mkdocs.yml over docs/, the CLI reference from the click commands),
# built strictly: a broken link or anchor fails the build
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir $(OUT)/site

bench: $(STAMP)
	$(BIN)/fieldloc bench

# $(call put_block,NAME,FILE,SOURCE,SUFFIX): the text between FILE's <!-- NAME:begin --> and
# <!-- NAME:end --> markers becomes SOURCE's text followed by SUFFIX (\n for a line break)
put_block = $(BIN)/python -c "import pathlib, re; r = pathlib.Path('$(2)'); \
	b = pathlib.Path('$(3)').read_text() + '$(4)'; \
	r.write_text(re.sub(r'(<!-- $(1):begin -->\n).*?(<!-- $(1):end -->)', \
	lambda m: m.group(1) + b + m.group(2), r.read_text(), flags=re.S))"

# docs/results.md's performance table, from a bench run (its JSON is kept in $(OUT)/bench.json);
# BENCH_RUNS="FULL.json AGAIN.json": no timing, the table of saved runs merged by row name (a
# later run's row replaces the earlier's: rows timed again alone after a loaded full run)
BENCH_RUNS ?=
bench-readme: $(STAMP)
	@mkdir -p $(OUT)
	$(if $(BENCH_RUNS),,$(FLP) bench --json $(OUT)/bench.json --overwrite > /dev/null)
	$(BIN)/fieldloc bench $(foreach f,$(or $(BENCH_RUNS),$(OUT)/bench.json),--from-json $(f)) \
		--format markdown > $(OUT)/bench.md
	$(call put_block,bench,docs/results.md,$(OUT)/bench.md,)

# The comparison of the methods in README.md and docs/manual.md (specs/compare.yaml: six rendered
# datasets, both cameras, clean and hard), from one batch: its table and summary picture between
# the compare markers of both files
COMPARE := $(OUT)/compare
compare: $(STAMP)
	@mkdir -p $(OUT) docs
	$(BIN)/fieldloc batch specs/compare.yaml -o $(COMPARE)
	cp $(COMPARE)/plots/summary.png docs/compare-summary.png
	$(call put_block,compare,docs/manual.md,$(COMPARE)/comparison.md,\n![methods x datasets](compare-summary.png)\n)
	$(call put_block,compare,README.md,$(COMPARE)/comparison.md,\n![methods x datasets](docs/compare-summary.png)\n)

# The demo: simulate a small omnidirectional MSL dataset, build the map, localise with the
# lookup tables frame by frame (as the robot would) and with the whole recording (--smooth),
# evaluate both against the truth and print the table.
DEMO := $(OUT)/demo-omni
demo: $(STAMP) $(DEMO)/truth.csv
	$(MAKE) --no-print-directory run-report DATA=$(DEMO) FIELD=$(FIELD)
	$(MAKE) --no-print-directory run-report DATA=$(DEMO) FIELD=$(FIELD) SMOOTH=1
	$(BIN)/fieldloc evaluate --table $(call run_dir,$(DEMO))/report \
		$(call run_dir,$(DEMO),1)/report

$(DEMO)/truth.csv: | $(STAMP)
	@mkdir -p $(OUT)
	$(FL) simulate omni --field $(FIELD) -o $(DEMO) --frames $(FRAMES) --seed $(SEED) --overwrite

# The template method of the SURF template paper (docs/references.md): template captures on
# a GRID m grid of the whole field and a run
# in the same venue by the same robot (calib and world seeds shared), templates.h5 from the
# grid, the run localised against it, evaluated.
GRID     ?= 1
TPL      := $(OUT)/templates-demo
templates-demo: $(STAMP) $(TPL)/runs/templates/report/report.json
	$(BIN)/fieldloc evaluate --table $(TPL)/runs/templates/report

$(TPL)/grid/truth.csv: | $(STAMP)
	@mkdir -p $(TPL)
	$(FLP) simulate omni --field $(FIELD) --grid $(GRID) -o $(TPL)/grid --seed $(SEED) \
		--calib-seed $(SEED) --world-seed $(SEED) --overwrite

$(TPL)/run/truth.csv: | $(STAMP)
	@mkdir -p $(TPL)
	$(FL) simulate omni --field $(FIELD) -o $(TPL)/run --frames $(FRAMES) --seed $$(($(SEED) + 1)) \
		--calib-seed $(SEED) --world-seed $(SEED) --overwrite

$(TPL)/templates.h5: $(TPL)/grid/truth.csv
	$(FLP) build-templates $(TPL)/grid -o $@ --overwrite

$(TPL)/runs/templates/poses.h5: $(TPL)/templates.h5 $(TPL)/run/truth.csv
	@mkdir -p $(dir $@)
	$(FLP) localize $(TPL)/run --method templates --templates $< -o $@ --overwrite

$(TPL)/runs/templates/report/report.json: $(TPL)/runs/templates/poses.h5
	$(FL) evaluate $< --truth $(TPL)/run/truth.csv -o $(TPL)/runs/templates/report \
		--overwrite > /dev/null

# File-based pipeline over any dataset folder: only stale steps run again.
#   make pipeline DATA=path/to/dataset FIELD=msl-2015 [METHOD=lut HEADING=imu|histogram|truth]
#                 [SMOOTH=1]
#   make pipeline DATA=path/to/kidsize-dataset FIELD=kidsize METHOD=mcl
pipeline: $(STAMP) $(RUN)/report/report.json
	$(BIN)/fieldloc evaluate --table $(RUN)/report

# the same steps without the table (the demo prints one table of its two runs)
run-report: $(STAMP) $(RUN)/report/report.json

$(MAP): $(FIELD_FILE) | $(STAMP)
	@mkdir -p $(dir $@)
	$(FL) build-map $(FIELD) -o $@ --overwrite

$(DATA)/features.h5: $(DATA)/calib.yaml $(wildcard $(DATA)/images/*) | $(STAMP)
	$(FLP) extract $(DATA) -o $@

$(RUN)/poses.h5: $(DATA)/features.h5 $(MAP)
	@mkdir -p $(dir $@)
	$(FLP) localize $(DATA) --map $(MAP) --features $< --method $(METHOD) $(HEADING_OPT) \
		$(SMOOTH_OPT) -o $@ --overwrite

# the table is printed once, by `pipeline`
$(RUN)/report/report.json: $(RUN)/poses.h5 $(DATA)/truth.csv
	$(FL) evaluate $< --truth $(DATA)/truth.csv -o $(RUN)/report --overwrite > /dev/null

clean:
	rm -rf $(OUT)
