#!/usr/bin/env bash
# What the lead runs on the GPU machine (device tool) after staging Warp with warp-pack.
# Usage: bash benchmarks/run_gpu.sh tests|bench|graph ...   (writes under $OUT; the device
# tool returns at most 8 files, so each mode packs its results into one tarball)
set -uo pipefail
export PYTHONPATH=.${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/extra .whl/*.whl \
    && export PYTHONPATH=$PYTHONPATH:/tmp/extra
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c 'import warp as wp, cv2, numpy, os; wp.config.quiet=True; wp.init(); print("warp", wp.__version__, "cv2", cv2.__version__, "threads", cv2.getNumThreads(), "cores", os.cpu_count())' 2>&1 | tail -1
for mode in "$@"; do
  case $mode in
    tests)
      WARPVX_TEST_BACKENDS=${WARPVX_TEST_BACKENDS:-cpu,cuda} timeout 400 python3 -m pytest -q -p no:cacheprovider \
        ${TESTS:-tests} > "$OUT/pytest_cuda.log" 2>&1; echo "pytest rc=$?"; tail -15 "$OUT/pytest_cuda.log" ;;
    bench)
      mkdir -p "$OUT/bench"
      timeout 400 python3 -m warpvx bench --graph --no-progress --out "$OUT/bench" ${BENCH_ARGS:-} > "$OUT/bench/bench.log" 2>&1
      echo "bench rc=$?"; grep -E "cuda:0|opencv|cvcuda" "$OUT/bench/bench.log" | awk '{print}' | tail -120
      tar -C "$OUT" -czf "$OUT/bench.tgz" bench && rm -rf "$OUT/bench" ;;
    graph)
      mkdir -p "$OUT/graph"
      timeout 400 python3 benchmarks/graph_bench.py --gpu cuda --out "$OUT/graph" ${GRAPH_ARGS:-} > "$OUT/graph/graph.log" 2>&1
      echo "graph rc=$?"; tail -40 "$OUT/graph/graph.log"
      tar -C "$OUT" -czf "$OUT/graph.tgz" graph && rm -rf "$OUT/graph" ;;
  esac
done
