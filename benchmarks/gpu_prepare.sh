#!/usr/bin/env bash
# Prepares, on a developer's machine with network access, what benchmarks/gpu.sh needs on a GPU
# machine that has none: Python 3.12 wheels of the packages its image lacks (.whl/) and the GL
# loader libraries (.gl/), both git-ignored through .git/info/exclude. The working tree that
# travels to the GPU machine is limited to 64 MiB, so Warp's wheel is slimmed: its CPU compiler
# (warp-clang.so, only needed for CPU kernels), examples and tests are left out.
#
#   bash benchmarks/gpu_prepare.sh            # then: bash benchmarks/gpu.sh on the GPU machine
#
# WARP_VERSION picks Warp's release (default below): its CUDA library must fit in the limit
# beside the other wheels (this script prints the total and fails over 60 MiB).
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
# 1.0.2: the newest release whose CUDA library, slimmed, leaves room for the rest within the
# limit (later releases' do not); lobelight's Warp engine keeps to the API it has.
WARP_VERSION=${WARP_VERSION:-1.0.2}
PY=${PYTHON:-python3}
exclude=$(git rev-parse --git-path info/exclude)
mkdir -p "$(dirname "$exclude")" && touch "$exclude"
for d in /.whl/ /.gl/; do grep -qxF "$d" "$exclude" || echo "$d" >>"$exclude"; done
rm -rf .whl && mkdir -p .whl
plat=()
for p in manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_17_x86_64 manylinux2014_x86_64 \
         manylinux1_x86_64 manylinux_2_5_x86_64 manylinux_2_34_x86_64 manylinux_2_35_x86_64; do
  plat+=(--platform "$p")
done
# what lobelight needs beyond the GPU image's packages (torch, numpy, scipy, numba, opencv,
# pillow, rich, tqdm, charset-normalizer are there)
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  "${plat[@]}" -d .whl trimesh==4.5.3 embreex moderngl glcontext platformdirs OpenEXR \
  "warp-lang==$WARP_VERSION"
# slim Warp: unpack, drop what CUDA kernels do not use, pack again as the same wheel
w=$(ls .whl/warp_lang-*.whl)
tmp=$(mktemp -d)
"$PY" - "$w" "$tmp" <<'PY'
import sys, zipfile
src, tmp = sys.argv[1], sys.argv[2]
drop = ("warp/bin/warp-clang.so", "warp/examples/", "warp/tests/", "warp/native/cutlass/")
with zipfile.ZipFile(src) as zin, zipfile.ZipFile(f"{tmp}/slim.whl", "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zout:
    for item in zin.infolist():
        if not item.filename.startswith(drop):
            zout.writestr(item, zin.read(item.filename))
PY
mv "$tmp/slim.whl" "$w" && rm -rf "$tmp"
# GL loaders (libglvnd, EGL) for the NVIDIA driver, unpacked there by benchmarks/gpu.sh
rm -rf .gl && mkdir -p .gl /tmp/amd64/partial
o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
apt-get "${o[@]}" update -qq
(cd .gl && apt-get "${o[@]}" download libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 >/dev/null)
total=$(du -cb .whl .gl | tail -1 | cut -f1)
tree=$(git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1)
echo "carry: .whl and .gl $((total / 1048576)) MiB, tracked files $((tree / 1048576)) MiB"
if [ $((total + tree)) -gt $((60 * 1048576)) ]; then
  echo "over 60 MiB: the GPU machine takes at most 64 MiB" >&2
  exit 1
fi
