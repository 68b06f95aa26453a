# Two commands set everything up on a fresh machine with Python 3.10+:
#   make demo   - venv + install, then the node runs live on a simulated bag over DDS
#   make test   - venv + install, then the test suite
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out
DEMO_DOMAIN ?= 42

.PHONY: all venv test lint demo bench soak docs figures mutation clean clean-kernels

all: test

$(STAMP): requirements.txt requirements-dev.txt setup.py package.xml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements-dev.txt
	$(BIN)/python -m pip install --quiet setuptools wheel
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	$(BIN)/laser_odom_warmup
	touch $(STAMP)

venv: $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist load test

lint: $(STAMP)
	$(BIN)/python -m flake8 laser_odom test setup.py
	$(BIN)/python -m pydocstyle laser_odom setup.py

demo: $(STAMP)
	rm -rf $(OUT)/demo && mkdir -p $(OUT)/demo
	$(BIN)/laser_odom_simulate $(OUT)/demo/sim_bag --world office --duration 60
	@echo "== starting laser_odom_node (ROS_DOMAIN_ID=$(DEMO_DOMAIN)) and replaying live over DDS"
	ROS_DOMAIN_ID=$(DEMO_DOMAIN) $(BIN)/laser_odom_node --ros-args \
	    --params-file config/default.yaml & node=$$!; \
	ROS_DOMAIN_ID=$(DEMO_DOMAIN) $(BIN)/laser_odom_replay $(OUT)/demo/sim_bag --live \
	    --reference $(OUT)/demo/sim_bag.tum --tum $(OUT)/demo/live.tum; status=$$?; \
	kill -INT $$node; wait $$node; exit $$status

bench: $(STAMP)
	$(BIN)/laser_odom_bench $(BENCH_ARGS)

soak: $(STAMP)
	$(BIN)/python -m laser_odom.tools.soak --scans 100000

docs: $(STAMP)
	$(BIN)/python -m laser_odom.ros.default_params > config/default.yaml
	$(BIN)/python -m laser_odom.ros.default_params --readme README.md
	$(BIN)/python -m laser_odom.tools.figures

# Mutation testing of one core module (cosmic-ray), e.g. make mutation MODULE=acceptance;
# python .ci/mutation.py --help lists the modules. Minutes (pure Python) to an hour (a
# matcher module, its kernels uncompiled) per module, in a temporary clone.
MODULE ?= se2
mutation: $(STAMP)
	$(BIN)/python .ci/mutation.py $(MODULE)

# The benchmark result behind the documented figures (needs ../shared/data; ~10 min on a
# quiet machine). Commit the JSON, then run make docs.
figures: $(STAMP)
	$(BIN)/laser_odom_bench --datasets fr079,mit-csail,intel,sim-office-360,sim-office-1081 \
	    --priors constant_velocity --reference-modes scan,local_map --no-search-table --quiet \
	    --json test/figures/benchmark.json

clean: clean-kernels
	rm -rf $(VENV) $(OUT) build install log *.egg-info

# numba keys each cached kernel by its own file's time stamp only: after editing one
# module, kernels elsewhere that call into it keep the old code until this runs.
clean-kernels:
	find laser_odom -name '*.nbi' -delete -o -name '*.nbc' -delete
