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
CHROMIUM_STAMP := $(VENV)/.installed-chromium
NEEDS := $(STAMP) $(if $(filter ray,$(BACKEND)),$(RAY_STAMP))
export PYTHONUNBUFFERED := 1

.PHONY: venv test test-verify smoke book clips bench budgets lint clean-build figure-% table-% reference-runs seeds confirmatory runs-% plan-% verify \
	thesis-budget ch4-readings-grid \
	verify-all chromium check-book ship-claims check-claims results

venv: $(STAMP)

# torch==2.13.0 goes in first (a CPU wheel lies on these machines); constraints.txt holds it and every other exact
# version there (pyproject.toml declares only compatible ranges).
PIP := $(BIN)/pip install -q --disable-pip-version-check -c constraints.txt
$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) torch==2.13.0 2>&1 | { grep -v "is ignored: it is neither" || true; }
	$(PIP) -e ".[dev,video,book]" 2>&1 | { grep -v "is ignored: it is neither" || true; }
	$(BIN)/python -m ipykernel install --sys-prefix --name python3 >/dev/null
	touch $(STAMP)

# the optional Ray extra (pyproject's [ray]): installed only for BACKEND=ray and for make test (its Ray tests)
$(RAY_STAMP): $(STAMP)
	$(PIP) -e ".[dev,video,book,ray]" 2>&1 | { grep -v "is ignored: it is neither" || true; }
	touch $(RAY_STAMP)

## make chromium : the browser test's headless Chromium (Debian's package), installed with apt-get when missing;
## a step of make test (no test installs anything)
chromium: $(CHROMIUM_STAMP)

$(CHROMIUM_STAMP): $(STAMP)
	@command -v chromium >/dev/null || command -v chromium-browser >/dev/null || { \
	  echo "installing chromium (Debian's package) for the browser test ..."; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; }
	touch $(CHROMIUM_STAMP)

## make check-book SCALE=small : after `make book SCALE=small`, open every page of that book in headless Chromium and
## check it as `make test` checks the smoke book: links and images, no table or figure wider than the text column,
## small figures click-to-enlarge, each page's first verdict within its first 1,400 px (tests/test_book.py)
check-book: $(CHROMIUM_STAMP)
	THESIS_REPRO_BOOK_HTML=$${THESIS_REPRO_BUILD:-$(CURDIR)/build}/$(SCALE)/book/_build/html \
	  $(BIN)/python -m pytest -q -p no:cacheprovider tests/test_book.py -k headless_chromium

## make figure-3.3 SCALE=small [TRAIN=1] : execute notebooks/fig-3.3.py at SCALE, write build/$(SCALE)/; a figure
## whose training runs are neither shipped nor cached refuses (naming their cost) unless TRAIN=1 (or RETRAIN=1)
figure-%: $(NEEDS)
	$(BIN)/python -m thesis_repro figure $* --scale $(SCALE) $(if $(JOBS),--jobs $(JOBS)) $(if $(TRAIN),--train)

table-%: $(NEEDS)
	$(BIN)/python -m thesis_repro figure table-$* --scale $(SCALE) $(if $(JOBS),--jobs $(JOBS)) $(if $(TRAIN),--train)

## make smoke : every notebook at SCALE=smoke (seconds each)
smoke: $(NEEDS)
	$(BIN)/python -m thesis_repro figure all --scale smoke

## make clips SCALE=small [FORCE=1] : render the chapter-3 landing page's clips (each basic learner's shipped
## policy under a perturbation, offscreen: MUJOCO_GL=egl) into build/$(SCALE)/clips; the book renders them too
clips: $(NEEDS)
	$(BIN)/python -m thesis_repro clips --scale $(SCALE) $(if $(FORCE),--force)

## make book SCALE=small [FORCE=1] [SHIPPED_ONLY=1 : skip notebooks that would train] : execute the changed
## notebooks at SCALE, build build/$(SCALE)/book/_build/html
book: $(NEEDS)
	$(BIN)/python -m thesis_repro book --scale $(SCALE) $(if $(FORCE),--force) $(if $(SHIPPED_ONLY),--shipped-only)

## make test : unit tests + doctests + papermill smoke run of every notebook + book build at smoke scale, in two
## processes (pytest -n 2: the smoke notebooks and the book share one, each module with a shared fixture stays in
## one; the longest work starts first, tests/conftest.py LONGEST_FIRST); lists the 40 slowest tests (budget: 10 min
## on 2 cores). Installs first what the tests need (the venv, Ray's extra, chromium); no test installs anything.
## CI runs it: it checks the shipped runs' keys and retrains the cheapest one (tests/test_shipped.py); make
## test-verify runs that retrain alone (marker retrains, as `make verify SCALE=small TRAIN=1` does)
test: $(STAMP) $(RAY_STAMP) $(CHROMIUM_STAMP)
	$(BIN)/ruff check thesis_repro tests notebooks
	$(call pytest_in_tmp,-n 2 --dist loadgroup --no-loadscope-reorder -q -rfEs --durations=40 \
	  --doctest-modules tests thesis_repro)

## make test-verify : the retrain of the cheapest shipped run alone (marker retrains; make test runs it too)
test-verify: $(STAMP)
	$(call pytest_in_tmp,-q -rfEs -m retrains tests)

# pytest with its arguments $(1), in a temporary run cache and build folder (removed after)
define pytest_in_tmp
	tmp=$$(mktemp -d); trap 'rm -rf "$$tmp"' EXIT; \
	export THESIS_REPRO_DATA=$$tmp/runs THESIS_REPRO_BUILD=$$tmp/build SB3_LOGDIR=$$tmp/sb3-log \
	  THESIS_REPRO_STAMPS=$$tmp/stamps; \
	$(BIN)/python -m pytest $(1) \
	  || { rc=$$?; [ $$rc -ne 5 ] || echo "error: pytest collected no tests"; exit $$rc; }
endef

## make reference-runs SCALE=small [FIGURES="3.3 4.1"] [COMMIT=1] [ALGOS="ppo ppo-16"] [SEEDS="0 1 2"] [KINDS=train] [UNTIL=22:40] :
## train every figure's training runs (cheapest first, resumable: re-run after an interruption) and ship them in
## data/reference; COMMIT=1 commits each as it lands; several SEEDS: the first one of every figure, then the others
## figure by figure (ORDER=item: every seed of an item before the next; ORDER=claims: item by item, ranked by claims
## settled per core-hour, chapter 5 to 10 seeds: `make plan-order`); KINDS="train evaluate" also ships each evaluation as soon as the run it loads has landed; UNTIL=HH:MM starts only jobs expected to end by then (a session's end: a run cut
## off there restarts on a new machine)
reference-runs: $(NEEDS)
	nice -n 10 $(BIN)/python -m thesis_repro reference-runs --scale $(SCALE) $(if $(FIGURES),--figures $(FIGURES)) \
	  $(if $(COMMIT),--commit) $(if $(JOBS),--jobs $(JOBS)) \
	  $(if $(ALGOS),--algos $(ALGOS)) $(if $(SEEDS),--seeds $(SEEDS)) $(if $(KINDS),--kind $(KINDS)) \
	  $(if $(UNTIL),--until $(UNTIL)) $(if $(ORDER),--order $(ORDER)) $(if $(STUDY),--study $(STUDY))

## make seeds UNTIL=HH:MM : the seed regeneration (every item to more training seeds), the one command a session starts in the background (nohup ... &):
## seeds 0-2 of every chapter 3-4 item under the thesis protocol, trained and evaluated, committed as they land, two
## at a time, item by item in SEED_ORDER (cheap, many-claim items first); UNTIL = the session's end
SEED_ORDER := table-3.3 4.4 4.7 4.2 3.4 table-3.6 table-3.4 3.3 3.7 table-3.5 3.5 table-3.7 3.6 3.8 4.1 4.3 4.5 4.6 3.2
seeds:
	$(MAKE) reference-runs SCALE=small SEEDS="0 1 2" KINDS="train evaluate" COMMIT=1 JOBS=2 \
	  FIGURES="$(SEED_ORDER)" $(if $(UNTIL),UNTIL=$(UNTIL))

## make confirmatory UNTIL=HH:MM : the confirmatory replication's one resumable command, started niced in the background (nohup ... &):
## seeds 3-5 of every chapter-3 item and the chapter-4 items 6 seeds can settle, chapter 5's CMA-ES items to seed 9,
## trained, evaluated and committed as they land, item by item in the order of claims settled per core-hour
## (`make plan-order SCALE=small SEEDS="3 4 5"`); UNTIL = the session's end
confirmatory:
	$(MAKE) reference-runs SCALE=small SEEDS="3 4 5" COMMIT=1 JOBS=2 ORDER=claims \
	  KINDS="train evaluate arm-solve arm-source arm-competitor-source arm-target arm-curriculum" \
	  $(if $(UNTIL),UNTIL=$(UNTIL))

## make thesis-budget UNTIL=HH:MM [COMMIT=0] [JOBS=1] [ALGOS=sac] [BACKEND=ray] : the thesis-budget study's one resumable command, started
## niced in the background (nohup ... &) once the claims design it is judged under (v3) is frozen (it refuses before):
## Fig 3.3's nine variants on Walker2d, HalfCheetah and Hopper, seeds 0-3, trained for the thesis's 4e6 steps and
## evaluated after 1M, 2M, 3M and 4M, each committed compactly into data/reference as it lands (COMMIT=0: not
## committed), two at a time, in the study's order (`python -m thesis_repro plan thesis-budget --rates shipped`);
## UNTIL = the session's end. `python -m thesis_repro plan thesis-budget --missing` counts what is left (0: done).
## ALGOS="sac" JOBS=1 beside ALGOS="<the others>" JOBS=1: SAC's 2.5-hour runs on one core, the rest on the other
## BACKEND=ray JOBS=92 (RAY_ADDRESS=auto): JOBS runs at a time as Ray tasks, landing here as they end (book/cluster.md)
thesis-budget:
	$(MAKE) reference-runs SCALE=small STUDY=thesis-budget KINDS="train evaluate" JOBS=$(or $(JOBS),2) \
	  $(if $(filter 0,$(COMMIT)),,COMMIT=1) $(if $(UNTIL),UNTIL=$(UNTIL)) $(if $(ALGOS),ALGOS="$(ALGOS)")

## make ch4-readings-grid UNTIL=HH:MM [COMMIT=0] [JOBS=1] : chapter 4's readings that train and differ from params_avg
## in their pilots (kl-avg-trpo, kl-avg-once), on every chapter-4 item at `small`'s seeds, each committed into
## data/reference as it lands (resumable; `python -m thesis_repro.runs.pilots ch4-readings --grid --price`: its cost);
## started niced in the background like `make thesis-budget`. Cheaper (about 8 core-hours): make it first
ch4-readings-grid: $(STAMP)
	nice -n 10 $(BIN)/python -m thesis_repro.runs.pilots ch4-readings --grid --jobs $(or $(JOBS),2) \
	  $(if $(filter 0,$(COMMIT)),,--commit) $(if $(UNTIL),--until $(UNTIL))

## make verify SCALE=small [N=20] [SEED=...] [TRAIN=1] [KINDS="evaluate arm-target"] [FIGURE=3.3 | ENTRY=<key or label> |
## CLAIM=<id>] : recompute a seeded random sample of N shipped evaluations on this machine (temporary cache) and
## compare: bit-identical wherever the numerics are pinned (the default; any difference is a mismatch, with its size),
## rollout means within 5 % only for entries made under THESIS_REPRO_NUMERICS=native on another CPU; prints a table
## (over 40 entries, only those not bit-identical), fails on a mismatch; TRAIN=1 also retrains the cheapest shipped
## training run (what tests/test_shipped.py's retrain test checks in `make test`); KINDS samples
## other shipped kinds too (chapter 5's arm-target, ...); FIGURE / ENTRY / CLAIM
## recompute every entry behind a figure, one entry, or a claim (then its pages' saved numbers too, compared with the
## shipped claims snapshot); STUDY=thesis-budget: that study's free integrity check instead (each learner without a
## budget-dependent schedule, at the small budget, is the shipped small run of the same seed bit for bit)
verify: $(STAMP)
	$(BIN)/python -m thesis_repro verify --scale $(SCALE) $(if $(N),-n $(N)) $(if $(SEED),--seed $(SEED)) \
	  $(if $(TRAIN),--train) $(if $(KINDS),--kind $(KINDS)) $(if $(FIGURE),--figure $(FIGURE)) \
	  $(if $(ENTRY),--entry $(ENTRY)) $(if $(CLAIM),--claim $(CLAIM)) $(if $(STUDY),--study $(STUDY))

## make verify-all SCALE=small : recompute every shipped evaluation (and chapter 5 entry) of the scale; prints the
## count and the compute they took when made before it starts
verify-all: $(STAMP)
	$(BIN)/python -m thesis_repro verify --scale $(SCALE) --all

## make ship-claims SCALE=small : after `make book SCALE=small`, copy the numbers every ledger page saved into the
## claims snapshot data/reference/claims/$(SCALE) (what a fresh clone's `claims` judges before its book; refuses
## pages not run or stale), then renders the book again (nothing re-executed) so that its pages read the
## calibrations the ship computed; make check-claims SCALE=small : after `make book`, compare this build's numbers
## with it
ship-claims: $(STAMP)
	$(BIN)/python -m thesis_repro claims --scale $(SCALE) --ship
	$(BIN)/python -m thesis_repro book --scale $(SCALE)

check-claims: $(STAMP)
	$(BIN)/python -m thesis_repro claims --scale $(SCALE) --check-snapshot

## make results : RESULTS.md and README.md's results and scale blocks, from the shipped claims snapshot at small
## (after `make ship-claims`; tests/test_results.py fails while they are out of date)
results: $(STAMP)
	$(BIN)/python -m thesis_repro results

## make runs-3.3 SCALE=small : where Figure 3.3's runs are (kind, label, key, cached / shipped / missing, path)
runs-%: $(STAMP)
	$(BIN)/python -m thesis_repro runs $* --scale $(SCALE)

## make budgets SCALE=small : training return of every cached/shipped run vs its budget (trained or still learning)
budgets: $(STAMP)
	$(BIN)/python -m thesis_repro budgets --scale $(SCALE)

## make plan-3.3 SCALE=full [CORES=64] [MISSING=1 : only what is neither cached nor shipped] [SEEDS="3 4 5"] : cost before running (jobs, env steps, throughput, core-hours, wall time);
## make plan-all SCALE=full : every figure and the book; make plan-order SCALE=small SEEDS="3 4 5" : the generator's order (claims settled per core-hour)
plan-%: $(STAMP)
	$(BIN)/python -m thesis_repro plan $* --scale $(SCALE) $(if $(CORES),--cores $(CORES)) $(if $(MISSING),--missing) \
	  $(if $(SEEDS),--seeds $(SEEDS))

## make bench : throughput benchmarks (batched evaluation, PPO training, ...), printed as ratios
bench: $(STAMP)
	$(BIN)/python -m thesis_repro bench

lint: $(STAMP)
	$(BIN)/ruff check thesis_repro tests notebooks
	$(BIN)/ruff format --check thesis_repro tests notebooks

clean-build:
	rm -rf build book/_build book/executed
