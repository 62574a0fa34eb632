# thesis_repro: every target bootstraps .venv from this repo's own files on first use.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SCALE ?= small
JOBS ?=
# RETRAIN=1 ignores the shipped reference runs (data/reference) and retrains them into data/runs.
ifdef RETRAIN
export THESIS_REPRO_RETRAIN := $(RETRAIN)
endif
# BACKEND=ray runs the jobs as Ray tasks (RAY_ADDRESS=... for a cluster; none: a local Ray); default local pool.
BACKEND ?=
ifdef BACKEND
export THESIS_REPRO_BACKEND := $(BACKEND)
endif
RAY_STAMP := $(VENV)/.installed-ray
NEEDS := $(STAMP) $(if $(filter ray,$(BACKEND)),$(RAY_STAMP))
export PYTHONUNBUFFERED := 1

.PHONY: venv test smoke book bench budgets lint clean-build figure-% table-% reference-runs seeds runs-% plan-% verify \
	ship-claims check-claims

venv: $(STAMP)

# torch==2.13.0 goes in first (a CPU wheel lies on these machines); the pin in pyproject keeps it there.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --disable-pip-version-check torch==2.13.0 2>&1 | { grep -v "is ignored: it is neither" || true; }
	$(BIN)/pip install -q --disable-pip-version-check -e ".[dev]" 2>&1 | { grep -v "is ignored: it is neither" || true; }
	$(BIN)/python -m ipykernel install --sys-prefix --name python3 >/dev/null
	touch $(STAMP)

# the optional Ray extra (pyproject's [ray]): installed only for BACKEND=ray and for make test (its Ray tests)
$(RAY_STAMP): $(STAMP)
	$(BIN)/pip install -q --disable-pip-version-check -e ".[dev,ray]" 2>&1 | { grep -v "is ignored: it is neither" || true; }
	touch $(RAY_STAMP)

## make figure-3.3 SCALE=small : execute notebooks/fig-3.3.py at SCALE, write build/$(SCALE)/
figure-%: $(NEEDS)
	$(BIN)/python -m thesis_repro figure $* --scale $(SCALE) $(if $(JOBS),--jobs $(JOBS))

table-%: $(NEEDS)
	$(BIN)/python -m thesis_repro figure table-$* --scale $(SCALE) $(if $(JOBS),--jobs $(JOBS))

## make smoke : every notebook at SCALE=smoke (seconds each)
smoke: $(NEEDS)
	$(BIN)/python -m thesis_repro figure all --scale smoke

## make book SCALE=small [FORCE=1] [SHIPPED_ONLY=1 : skip notebooks that would train] : execute the changed
## notebooks at SCALE, build build/$(SCALE)/book/_build/html
book: $(NEEDS)
	$(BIN)/python -m thesis_repro book --scale $(SCALE) $(if $(FORCE),--force) $(if $(SHIPPED_ONLY),--shipped-only)

## make test : unit tests + doctests + papermill smoke run of every notebook + book build at smoke scale; lists the
## 15 slowest tests (CI has 90 min on 2 cores; keep the whole well under 30)
test: $(STAMP) $(RAY_STAMP)
	$(BIN)/ruff check thesis_repro tests notebooks
	tmp=$$(mktemp -d); trap 'rm -rf "$$tmp"' EXIT; \
	export THESIS_REPRO_DATA=$$tmp/runs THESIS_REPRO_BUILD=$$tmp/build SB3_LOGDIR=$$tmp/sb3-log; \
	$(BIN)/python -m pytest -q -rfEs --durations=15 --doctest-modules tests thesis_repro \
	  || { rc=$$?; [ $$rc -ne 5 ] || echo "error: pytest collected no tests"; exit $$rc; }

## make reference-runs SCALE=small [FIGURES="3.3 4.1"] [COMMIT=1] [ALGOS="ppo ppo-16"] [SEEDS="0 1 2"] [KINDS=train] [UNTIL=22:40] :
## train every figure's training runs (cheapest first, resumable: re-run after an interruption) and ship them in
## data/reference; COMMIT=1 commits each as it lands; several SEEDS: the first one of every figure, then the others
## figure by figure; KINDS="train evaluate" also ships each evaluation as soon as the run it loads has landed; UNTIL=HH:MM starts only jobs expected to end by then (a session's end: a run cut
## off there restarts on a new machine)
reference-runs: $(STAMP)
	nice -n 10 $(BIN)/python -m thesis_repro reference-runs --scale $(SCALE) $(if $(FIGURES),--figures $(FIGURES)) \
	  $(if $(COMMIT),--commit) $(if $(JOBS),--jobs $(JOBS)) \
	  $(if $(ALGOS),--algos $(ALGOS)) $(if $(SEEDS),--seeds $(SEEDS)) $(if $(KINDS),--kind $(KINDS)) \
	  $(if $(UNTIL),--until $(UNTIL))

## make seeds UNTIL=HH:MM : issue 22's regeneration, the one command a session starts in the background (nohup ... &):
## seeds 0-2 of every chapter 3-4 item under the thesis protocol, trained and evaluated, committed as they land, two
## at a time, item by item in SEED_ORDER (cheap, many-claim items first); UNTIL = the session's end
SEED_ORDER := table-3.3 4.4 4.7 4.2 3.4 table-3.6 table-3.4 3.3 3.7 table-3.5 3.5 table-3.7 3.6 3.8 4.1 4.3 4.5 4.6 3.2
seeds:
	$(MAKE) reference-runs SCALE=small SEEDS="0 1 2" KINDS="train evaluate" COMMIT=1 JOBS=2 \
	  FIGURES="$(SEED_ORDER)" $(if $(UNTIL),UNTIL=$(UNTIL))

## make verify SCALE=small [N=20] [SEED=...] [TRAIN=1] [KINDS="evaluate arm-target"] : recompute a seeded random
## sample of N shipped evaluations on this machine (temporary cache) and compare: bit-identical on the platform that
## made them, else rollout means within 5 %; prints a table, fails on a mismatch; TRAIN=1 also retrains the cheapest
## shipped training run; KINDS samples other shipped kinds too (chapter 5's arm-target, arm-source, ...)
verify: $(STAMP)
	$(BIN)/python -m thesis_repro verify --scale $(SCALE) $(if $(N),-n $(N)) $(if $(SEED),--seed $(SEED)) \
	  $(if $(TRAIN),--train) $(if $(KINDS),--kind $(KINDS))

## make ship-claims SCALE=small : after `make book SCALE=small`, copy the numbers every ledger page saved into the
## claims snapshot data/reference/claims/$(SCALE) (what a fresh clone's `claims` judges before its book; refuses
## pages not run or stale); make check-claims SCALE=small : after `make book`, compare this build's numbers with it
ship-claims: $(STAMP)
	$(BIN)/python -m thesis_repro claims --scale $(SCALE) --ship

check-claims: $(STAMP)
	$(BIN)/python -m thesis_repro claims --scale $(SCALE) --check-snapshot

## make runs-3.3 SCALE=small : where Figure 3.3's runs are (kind, label, key, cached / shipped / missing, path)
runs-%: $(STAMP)
	$(BIN)/python -m thesis_repro runs $* --scale $(SCALE)

## make budgets SCALE=small : training return of every cached/shipped run vs its budget (trained or still learning)
budgets: $(STAMP)
	$(BIN)/python -m thesis_repro budgets --scale $(SCALE)

## make plan-3.3 SCALE=full [CORES=64] [MISSING=1 : only what is neither cached nor shipped] : cost before running (jobs, env steps, throughput, core-hours, wall time);
## make plan-all SCALE=full : every figure and the book
plan-%: $(STAMP)
	$(BIN)/python -m thesis_repro plan $* --scale $(SCALE) $(if $(CORES),--cores $(CORES)) $(if $(MISSING),--missing)

## make bench : throughput benchmarks (batched evaluation, PPO training, ...), printed as ratios
bench: $(STAMP)
	$(BIN)/python -m thesis_repro.bench

lint: $(STAMP)
	$(BIN)/ruff check thesis_repro tests notebooks
	$(BIN)/ruff format --check thesis_repro tests notebooks

clean-build:
	rm -rf build book/_build book/executed
