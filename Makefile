# Every target sets up what it needs: a fresh clone needs only python3 (>=3.11) and a C compiler.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# Solver library sources that generated folders copy in (DAQP's sdist from PyPI, MIT): fetched once
# into $(VENV)/share/ddpc-codegen, never committed; generation itself then stays offline.
LIBS_STAMP := $(VENV)/.solver-sources

.PHONY: install check test test-durations lint docs demo codegen fuzz adapt-eval bench bridge-demo sitl-demo sitl-adapt proxy-demo proxy-soak clean

install: $(STAMP) $(LIBS_STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -m pip install -q --disable-pip-version-check --upgrade pip
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[dev]'
	@# MAVProxy as a ground station in the SITL tier; --no-deps: its GUI modules' opencv and vtk are not needed
	@$(PY) -m pip install -q --disable-pip-version-check --no-deps 'MAVProxy>=1.8,<2'
	@touch $(STAMP)
	@echo "installed ddpc-codegen into $(VENV)"

$(LIBS_STAMP): ddpc_codegen/codegen/libs.py | $(STAMP)
	@$(PY) -c "from ddpc_codegen.codegen.libs import main; raise SystemExit(main(['fetch']))"
	@touch $(LIBS_STAMP)

# While you work: lint, then the unit tier (no test that compiles C, runs processes over sockets, waits on the
# wall clock, flies a SITL or was measured slow in tests/durations.json), one xdist worker per core, a file
# per worker. Under a minute on 2 cores; `make test` before a commit or push runs every tier.
CHECK_TIERS := e2e or realtime or compiler or sitl or slow
CHECK_WORKERS ?= $(shell $(PYTHON) -c "import os; print(os.cpu_count() or 1)")
check: install lint
	@$(PY) -m pytest -q -n $(CHECK_WORKERS) --dist loadfile -m "not ($(CHECK_TIERS))" $(PYTEST_ARGS)

# Lint first (seconds), then every test tier (markers: e2e, realtime, compiler, sitl, slow; select
# one with `$(PY) -m pytest -m compiler`) in two phases: what tolerates a second process runs on
# TEST_WORKERS pytest-xdist workers, a test file per worker (module fixtures built once); the tiers
# that measure wall-clock time then run without it: the realtime tier on three workers (its flights wait on
# the wall clock: a real-time bridge + simulated vehicle pair needs about a quarter of a core; the tests of one
# module fixture stay together, tests/conftest.py), then the SITL tier on two
# (a SITL test waits on a real-time autopilot; tests/sitl/conftest.py groups them). Every phase runs
# (unless interrupted) and the target fails if one fails, or if none ran a test (PYTEST_ARGS may
# narrow them); solvers are built once for all (DDPC_TEST_CACHE, tests/support/solver_cache.py).
# Each test process runs one BLAS thread (tests/conftest.py), so the workers do not oversubscribe the cores.
# Bytecode is written even where PYTHONDONTWRITEBYTECODE is set (ignored __pycache__ folders): else every worker of
# every phase rewrites the test modules' asserts (~3.5 s of CPU each) and every bridge, vehicle or CLI process
# the tests start compiles the package's modules again (~0.1 s each).
# Two workers per core: about half of that phase's test time is spent waiting (lock-step vehicle and bridge
# processes, timeouts on the wall clock), measured 7:46 with 4 workers vs 9:05 with 2 on this 2-core machine.
TEST_WORKERS ?= $(shell $(PYTHON) -c "import os; print(2 * (os.cpu_count() or 1))")
SERIAL_TIERS := realtime or sitl
PHASE_RC = r=$$?; [ $$r -eq 2 ] && exit 2; [ $$r -eq 5 ] || { ran=1; [ $$r -eq 0 ] || rc=$$r; }
test: install lint
	@export DDPC_TEST_CACHE=$$(mktemp -d); unset PYTHONDONTWRITEBYTECODE; rc=0; ran=0; \
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not ($(SERIAL_TIERS))" $(PYTEST_ARGS); $(PHASE_RC); \
	$(PY) -m pytest -q -n 3 --dist loadgroup -m "realtime and not sitl" $(PYTEST_ARGS); $(PHASE_RC); \
	$(PY) -m pytest -q -n 2 --dist loadgroup -m sitl $(PYTEST_ARGS); $(PHASE_RC); \
	rm -rf $$DDPC_TEST_CACHE; [ $$ran -eq 1 ] || rc=5; exit $$rc

# Re-measure every test serially into tests/durations.json (sets the `slow` marker; see tests/conftest.py).
test-durations: install
	$(PY) -m pytest -q --record-durations $(PYTEST_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# The docs site (mkdocs, warnings are errors) into build/docs; the reference pages are generated from
# the code while it builds. It needs the venv only, not the solver library sources. tests/test_docs.py
# builds it too, so `make test` checks it.
docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict --site-dir build/docs

# Each measuring target ends by rendering its reports/*.json into docs/results/ and the README table.
RENDER := $(PY) -m ddpc_codegen.docsgen.results

# The main job: both scenarios with and without steering; table, reports/summary.json, figures.
demo: install
	$(PY) -m ddpc_codegen.experiments.demo
	$(RENDER)

# Steering solvers from configs/. A missing dataset is recorded on the simulator first
# (hopping: aerial data, ground phases replaced by artificial IO, hops stitched into H_G).
data/flying.npz: | install
	$(PY) -c "from ddpc_codegen.experiments.pipeline import build_setup; build_setup('flying', generate_dir=None, progress=True)"

data/hopping_raw.npz: | install
	$(PY) -c "from ddpc_codegen.experiments.pipeline import build_setup; build_setup('hopping', generate_dir=None, progress=True)"

codegen: install data/flying.npz data/hopping_raw.npz
	$(VENV)/bin/ddpc-codegen codegen configs/flying.toml configs/hopping.toml

# Vehicle and bridge as two processes over UDP on 127.0.0.1: collect, codegen, baseline and steered flights, the
# steered flight again quiet and under a 10 kHz flood from foreign addresses; reports/bridge.json, docs/results/bench.md.
bridge-demo: install
	$(PY) -m ddpc_codegen.testbed.bridge_demo $(if $(SCENARIO),--scenario $(SCENARIO))
	$(RENDER)

# Real autopilots (docs/guides/px4.md and ardupilot.md say how to build them; found through DDPC_ARDUPILOT_SITL and
# DDPC_PX4_SITL): from the ground, baseline -> collect -> codegen -> steer, each SITL in a private
# network namespace; reports/sitl.json and the flight logs in reports/sitl_<autopilot>/.
sitl-demo: install
	$(PY) -m ddpc_codegen.testbed.sitl_demo
	$(RENDER)

# Fuzzing what the bridge flies on (ddpc_codegen/testbed/fuzz.py): mutants of the dynamics of every input that
# defines the path (profiles, trajectory files, prefilters, feed-forward tables, excitation, flags; their numbers
# and their raw bytes), each refused with one line or, accepted, flown in-process lock-step against the simulated
# vehicle (the bridge's and ddpc-vehicle's own classes) until 1000 have flown; a sample of them again as
# ddpc-vehicle + ddpc-bridge processes; the MAVLink input attacked in flight (foreign and same-address peers,
# absurd values, stamps, corrupted bytes, a 10 kHz flood). Judged on the vehicle's true position in its envelope
# and every reference step against the rate bound: a table, reports/fuzz.json, exit 1 on a violation (replay one
# with --replay SEED); steered mutants too once `make codegen` has built generated/flying. Then each file kind's
# keys mutated (1000 files per kind: refused with a precise error or loaded with finite values). Under 5 min on
# 2 cores.
fuzz: install
	$(PY) -m ddpc_codegen.testbed.fuzz $(if $(wildcard generated/flying/manifest.json),--solver generated/flying)
	DDPC_FUZZ_EXAMPLES=1000 $(PY) -m pytest -q -p no:cacheprovider -k mutated \
		tests/firmware_bridge/test_baseline_modes.py tests/robot/test_profile.py tests/robot/test_trajectory_files_fuzz.py

# A user's own pymavlink app flown on the ArduCopter and PX4 SITLs directly, through ddpc-proxy in pass-through, and
# steered (a local preview and a declared delay; the proxy measuring on the lab's motion capture) on three paths,
# after one collect flight through the proxy and codegen; the true height judges (reports/proxy.json,
# docs/results/proxy.md; flights and logs in reports/proxy_<autopilot>/).
proxy-demo: install
	$(PY) -m ddpc_codegen.testbed.proxy_demo
	$(RENDER)

# ddpc-proxy (transparent) in front of ddpc-vehicle: a pymavlink app at 50 Hz and a ground station for 10 minutes,
# then 2 minutes under a 10 kHz foreign flood; every app setpoint checked at the vehicle (once, in order, unchanged),
# the added latency from the proxy's stamps and from both ends (reports/proxy_soak.json; logs in reports/proxy_soak/).
proxy-soak: install
	$(PY) -m ddpc_codegen.testbed.proxy_soak --minutes 10 --flood-hz 10000 --flood-minutes 2
	$(RENDER)

# Online adaptation on the PX4 and ArduCopter SITLs: a motor's thrust loss and a heavier vehicle applied mid-flight
# (by the harness, over a second MAVLink link), static vs adapted steering (ddpc-bridge --adapt) vs the prefilter;
# adds `adaptation` to reports/sitl.json.
sitl-adapt: install
	$(PY) -m ddpc_codegen.testbed.sitl_adapt
	$(RENDER)

# Online predictor updates in-process: a vehicle change mid-flight, adapted vs static vs prefilter.
adapt-eval: install
	$(VENV)/bin/ddpc-codegen adapt-eval
	$(RENDER)

bench: install
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[dev,bench]' || echo "(bench extra not installed: the CVXPYgen comparison is skipped)"
	$(PY) -m ddpc_codegen.experiments.bench
	$(RENDER)

clean:
	rm -rf build generated/*/ reports/*.json reports/*.png .pytest_cache
