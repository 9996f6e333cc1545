#!/usr/bin/env bash
# A Ray cluster of N nodes on this machine, on loopback (docs/bench.md): a head and N-1 workers, each its own
# `ray start` process with its own raylet, one CPU each. The benches reach it with --address 127.0.0.1:PORT, the
# same code that runs on a real cluster.
#
#   docs/scripts/local_ray_cluster.sh start [N] [PORT]   # default 4 nodes on port 6390
#   lcmesh bench suite --address 127.0.0.1:6390 ...
#   docs/scripts/local_ray_cluster.sh stop
set -euo pipefail
# token authentication, as ray.init() uses it: every node and client reads the token in ~/.ray/auth_token
export RAY_AUTH_MODE="${RAY_AUTH_MODE:-token}"
RAY="${RAY:-$(dirname "$(command -v lcmesh || echo .venv/bin/lcmesh)")/ray}"
[ -x "$RAY" ] || RAY=ray
case "${1:-}" in
  start)
    nodes="${2:-4}"
    port="${3:-6390}"
    if ! [[ "$nodes" =~ ^[1-9][0-9]*$ ]]; then echo "nodes must be a positive integer, got '$nodes'" >&2; exit 2; fi
    "$RAY" start --head --node-ip-address=127.0.0.1 --port="$port" --num-cpus=1 --include-dashboard=false \
      --disable-usage-stats > /dev/null
    for _ in $(seq 2 "$nodes"); do
      "$RAY" start --address="127.0.0.1:$port" --node-ip-address=127.0.0.1 --num-cpus=1 --disable-usage-stats > /dev/null
    done
    for _ in $(seq 30); do  # the workers register with the head in a few seconds
      active=$("$RAY" status --address="127.0.0.1:$port" 2>/dev/null | sed -n '/Active:/,/Pending:/p' | grep -c node_ || true)
      [ "$active" -ge "$nodes" ] && break
      sleep 1
    done
    echo "$active of $nodes nodes active"
    echo "cluster of $nodes nodes at 127.0.0.1:$port (stop: $0 stop)"
    ;;
  stop)
    "$RAY" stop --force > /dev/null
    echo "stopped"
    ;;
  *)
    echo "usage: $0 start [NODES] [PORT] | stop" >&2
    exit 2
    ;;
esac
