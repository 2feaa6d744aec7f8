# uavsim: two commands from a fresh clone, `make demo` and `make test`.
# The venv is created on first use; torch is pinned to the CPU wheel first so
# that the package's torch range is already satisfied (no CUDA download).

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.uavsim-installed
OUT    ?= out
LOOPS  ?= altitude attitude altitude-second
# test worker processes (pytest-xdist; 0: in this process). CI has 2 cores; each worker takes whole
# test files (--dist loadfile), so a file's module fixtures are built once
TEST_JOBS ?= 2
export RERUN_ANALYTICS := 0

.PHONY: demo test test-slow lint bench generate-data train replay clean help

help:
	@echo "make demo            relay episodes on every loop, tuning and a session round trip"
	@echo "make test            install and run the tests (CI runs this)"
	@echo "make test-slow       also the long checks (minutes)"
	@echo "make bench           benchmarks (ratios against same-run baselines)"
	@echo "make replay          Rerun recording of the demo episode"
	@echo "make generate-data   training sets into datasets/ (LOOPS=\"altitude attitude altitude-second\" or LOOPS=lateral)"
	@echo "make train           networks into training/runs/ from those sets"

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e ".[dev]"   # dev = train (torch), logs, dask and the test tools
	touch $(STAMP)

demo: $(STAMP)
	@mkdir -p $(OUT)
	@echo "== DNN-NP-MRFT end to end on the small embedded default: generate -> train -> identify"
	$(BIN)/uavsim generate datasets/small.toml --out datasets/small.h5
	$(BIN)/uavsim train training/small.toml
	$(BIN)/uavsim identify scenarios/sessions/altitude-npmrft --models training/runs/small --plot $(OUT)/identify.png
	@echo "(picture: $(OUT)/identify.png; training curves: training/runs/small/training.png)"
	@echo "(truth of that session:)"; cat scenarios/sessions/altitude-npmrft.truth.json; echo
	@echo "== relay (MRFT beta=-0.73) on each loop of the MuJoCo hexarotor, against the exact lumped cycle"
	$(BIN)/uavsim sim relay --duration 15 --session $(OUT)/demo-sessions
	@echo "== the same episode read back as a flight session"
	$(BIN)/uavsim session check $(OUT)/demo-sessions/altitude
	@echo "== tuning rule for the paper's altitude process (Table I, normal camera with KF)"
	$(BIN)/uavsim tune --loop altitude --T-prop 0.3 --T1 0.2 --tau 0.0128
	@echo "== noise estimate of the saved episode"
	$(BIN)/uavsim noise $(OUT)/demo-sessions/altitude
	@echo "== Rerun recording of the episode (limit cycle, switches, extrema, phase portrait)"
	$(BIN)/uavsim replay $(OUT)/demo-sessions/altitude --save $(OUT)/demo-altitude.rrd

test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_JOBS) --dist loadfile

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_JOBS) --dist loadfile -m "slow or not slow" --timeout 0

lint: $(STAMP)
	$(BIN)/ruff check uavsim tests docs

bench: $(STAMP)
	$(BIN)/uavsim bench sim
	$(BIN)/uavsim bench generate
	OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 $(BIN)/uavsim bench infer --models training/runs/small

replay: $(STAMP)
	$(BIN)/uavsim replay $(OUT)/demo-sessions/altitude --save $(OUT)/demo-altitude.rrd
	@if [ -f datasets/small.h5 ]; then \
	  $(BIN)/uavsim replay datasets/small.h5 --class 1 --episode 5 --save $(OUT)/demo-small-class1-episode5.rrd; \
	else echo "make replay: no datasets/small.h5 (make demo writes it); dataset replay skipped"; fi

generate-data: $(STAMP)
	@for l in $(LOOPS); do \
	  test -f datasets/$$l.toml || { echo "make generate-data: no recipe datasets/$$l.toml"; exit 2; }; \
	  $(BIN)/uavsim generate datasets/$$l.toml --out datasets/$$l.h5 || exit $$?; \
	  if [ -f datasets/$$l-test.toml ]; then $(BIN)/uavsim generate datasets/$$l-test.toml --out datasets/$$l-test.h5 || exit $$?; fi; \
	done

train: $(STAMP)
	@for l in $(LOOPS); do $(BIN)/uavsim train training/$$l.toml || exit $$?; done

clean:
	rm -rf $(OUT) .pytest_cache
