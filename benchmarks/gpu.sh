#!/usr/bin/env bash
# Every GPU benchmark in one go, on a machine with one CUDA GPU, in under 10 minutes:
#   prefilter (base 512), rays (Warp on the device beside Embree), bake of 11.5K and 45.7K
#   vertices (N = 1, the default interreflection), render at 50K vertices, 1024^2, N = 1 and 3.
# Writes gpu.json (the summary `lobelight bench all` writes), gpu.md (the Markdown table of
# docs/benchmarks.md, made from gpu.json), gpu.log (stderr) and nvidia-smi.csv to $OUT
# (default benchmarks/out). Packages the machine lacks come from .whl/ and the GL loaders from
# .gl/, both prepared by benchmarks/gpu_prepare.sh; a machine with lobelight installed needs
# neither.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-$PWD/benchmarks/out}
mkdir -p "$OUT"
if compgen -G ".gl/*.deb" >/dev/null; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
nv=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$nv" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=${__EGL_VENDOR_LIBRARY_FILENAMES:-$nv}
if compgen -G ".whl/*.whl" >/dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH=$PWD/src${PYTHONPATH:+:$PYTHONPATH}
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv \
  >"$OUT/nvidia-smi.csv" 2>&1
# the budget leaves the last benchmark room to finish inside the 10 minutes
timeout 570 python3 -m lobelight.cli bench all --device cuda --budget 420 -o "$OUT/gpu.json" \
  --json >"$OUT/gpu.stdout.json" 2>"$OUT/gpu.log"
echo "bench all: exit $?"
tail -n 20 "$OUT/gpu.log"
python3 -m lobelight.bench table "$OUT/gpu.json" | tee "$OUT/gpu.md"
