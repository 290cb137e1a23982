#!/usr/bin/env bash
# Builds `rtf` for the lent GPU machine, whose image carries PyTorch 2.11 (+cu130) rather than
# the 2.13 that tch 0.26 is generated for (docs/src/getting-started.md, GPUs). Run it here, on
# the build machine:
#   1. fetches the torch 2.11.0 wheel from the package registry (about 530 MB) and unpacks its
#      headers and libraries;
#   2. copies torch-sys 0.26 from cargo's registry and makes the generated wrapper functions
#      that 2.11 lacks raise instead (they are found by compiling: philox RNG, lanczos
#      upsampling, an in-place flash-attention variant, an MPS attention signature; rtf uses
#      none of them);
#   3. builds `rtf` in a separate worktree and target folder, with torch-sys patched, and writes
#      a stripped copy to OUT (default .gpu/rtf, git-ignored; carry `.gpu` to the machine);
#   4. builds the Python package there too, for the machine's python3 (3.12) and torch 2.11,
#      into OUT's folder /wheel (maturin from .venv, a Python 3.12 found here: PYTHON312, else
#      pyenv's, else python3.12 on PATH). Its torch version check is set to 2.11.0 in the
#      worktree only: a lab build for scripts/gpu_check.sh's `python` phase, never released.
# There: LD_LIBRARY_PATH=<torch>/lib plus its nvidia/*/lib folders (see docs/src/
# getting-started.md); `cargo xtask reproduce ... --no-build` after copying it to
# target/release/rtf.
# Usage: scripts/gpu_build.sh [OUT] [WORK]   (WORK default /tmp/rtf-gpu-build)
set -euo pipefail
repo=$(git rev-parse --show-toplevel)
out=$(realpath -m "${1:-$repo/.gpu/rtf}")
work=$(realpath -m "${2:-/tmp/rtf-gpu-build}")
version=2.11.0
mkdir -p "$work"
cd "$work"
if [ ! -d torch/include ]; then
    python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
        --implementation cp --platform manylinux_2_28_x86_64 -d wheel "torch==$version"
    unzip -q wheel/torch-"$version"-*.whl 'torch/include/*' 'torch/lib/*' 'torch/share/*'
fi
sys=$work/torch-sys
if [ ! -d "$sys" ]; then
    cp -r "$(ls -d ~/.cargo/registry/src/*/torch-sys-0.26.0 | head -1)" "$sys"
fi
tree=$work/tree
if [ ! -d "$tree" ]; then
    git -C "$repo" worktree prune # a worktree of an earlier WORK that is gone since
    git -C "$repo" worktree add --detach "$tree" HEAD
fi
# -f: the last build's edits (Cargo.lock's patched torch-sys, the wheel's version check) go.
git -C "$tree" checkout -q -f --detach "$(git -C "$repo" rev-parse HEAD)"
ln -sfn "$work/torch" "$tree/.libtorch"

build() {
    (cd "$tree" && CARGO_TARGET_DIR="$tree/target" cargo build --release -p rtf-cli \
        --config "patch.crates-io.torch-sys.path=\"$sys\"" 2>&1 | tee "$work/build.log")
}
# Each failing build names the wrapper lines 2.11 cannot compile; make those functions raise.
for attempt in 1 2 3; do
    if build; then break; fi
    python3 - "$sys/libtch/torch_api_generated.cpp" "$work/build.log" <<'PY'
import re, sys
src_path, log_path = sys.argv[1:]
lines = sorted({int(m.group(1)) for m in re.finditer(
    r"torch_api_generated\.cpp:(\d+):\d+: error", open(log_path).read())}, reverse=True)
if not lines:
    sys.exit("the build failed for another reason: see " + log_path)
src = open(src_path).read().split("\n")
for n in lines:
    i = n - 1
    assert "outputs__ =" in src[i], src[i]
    j = i + 1
    while src[j].strip() != ")":
        j += 1
    src[i:j] = ['    throw std::runtime_error("not in libtorch 2.11 (rtf GPU build)");']
open(src_path, "w").write("\n".join(src))
print(f"patched {len(lines)} wrapper functions")
PY
done
mkdir -p "$(dirname "$out")"
strip -o "$out" "$tree/target/release/rtf"
echo "wrote $out"

python312=${PYTHON312:-$(ls -d ~/.pyenv/versions/3.12*/bin/python3.12 2>/dev/null | tail -1)}
python312=${python312:-$(command -v python3.12)}
"$python312" -c 'import sys; assert sys.version_info[:2] == (3, 12)' ||
    { echo "no Python 3.12 to build the wheel for (set PYTHON312)"; exit 1; }
wheels=$(dirname "$out")/wheel
rm -rf "$wheels"
sed -i "s/^TORCH_VERSION = .*/TORCH_VERSION = \"$version\"/" "$tree/crates/rtf-py/python/rtf/__init__.py"
sed -i "s/\"torch==[0-9.]*\"/\"torch==$version\"/" "$tree/crates/rtf-py/pyproject.toml"
(cd "$tree" && PYO3_PYTHON="$python312" CARGO_TARGET_DIR="$tree/target" "$repo/.venv/bin/python" -m maturin \
    build --release --strip --auditwheel skip --compatibility linux -m crates/rtf-py/Cargo.toml \
    -i "$python312" --out "$wheels" --config "patch.crates-io.torch-sys.path=\"$sys\"")
echo "wrote $(ls "$wheels"/*.whl)"
