#!/usr/bin/env bash
# What the lead runs on the GPU machine (device tool) after staging Warp with warp-pack.
# Usage: bash benchmarks/run_gpu.sh tests|bench|graph|all   (writes under $OUT)
set -uo pipefail
export PYTHONPATH=.${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/extra .whl/*.whl \
    && export PYTHONPATH=$PYTHONPATH:/tmp/extra
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c 'import warp as wp, cv2, numpy; wp.config.quiet=True; wp.init(); print("warp", wp.__version__, "cv2", cv2.__version__, "numpy", numpy.__version__, wp.get_devices())'
mode=${1:-all}
if [[ $mode == tests || $mode == all ]]; then
  WARPVX_TEST_BACKENDS=${WARPVX_TEST_BACKENDS:-cuda} timeout 560 python3 -m pytest -q -x -p no:cacheprovider \
    ${TESTS:-tests} 2>&1 | tee "$OUT/pytest_cuda.log" | tail -25
fi
if [[ $mode == bench || $mode == all ]]; then
  timeout 560 python3 -m warpvx bench --graph --no-progress --out "$OUT" ${BENCH_ARGS:-} 2>&1 | tee "$OUT/bench.log" | tail -80
fi
if [[ $mode == graph ]]; then
  timeout 560 python3 benchmarks/graph_bench.py --gpu cuda --out "$OUT" ${GRAPH_ARGS:-} 2>&1 | tee "$OUT/graph.log" | tail -60
fi
