# fieldloc: `make demo` and `make test` work on a fresh clone with nothing but Python 3.10+.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
FL     := $(BIN)/fieldloc
STAMP  := $(VENV)/.installed

OUT    ?= build
FIELD  ?= msl-2015
DATA   ?= $(OUT)/demo-omni
FRAMES ?= 100
SEED   ?= 1

.PHONY: install test lint demo bench pipeline clean

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(FL) bench

demo: $(STAMP)
	@mkdir -p $(OUT)
	$(FL) build-map $(FIELD) -o $(OUT)/$(FIELD).map.h5
	$(FL) inspect $(OUT)/$(FIELD).map.h5

clean:
	rm -rf $(OUT)
