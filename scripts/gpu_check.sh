#!/usr/bin/env bash
# Issue 40 in one run on a lent GPU machine (docs/src/gpu.md): correctness on the GPU, the
# inference and training tables against PyTorch (lab/gpu/gpu_bench.py), scripts/gpu_smoke.sh,
# then extras while the time budget lasts. Every phase writes its file under OUT at once, so a
# run cut off by its time limit keeps what it finished. On the H100 of 2026-11-27 the phases
# took: correct 33 s, smoke 150 s, train 258 s (with two diagnostic runs, now left out), infer
# 209 s for six network-batch pairs (now seven). Issue 60's second round adds CMX-B2 (its logits
# in `correct`, its AdamW training in `train`) and the Python package (`python`): the plan for a
# 15-minute lease, `env correct train` in one call and `infer python` in a second started at once
# while the machine is warm, is in docs/src/gpu.md, "Next device session".
#
# Usage, on the GPU machine from the repo root, with `rtf` built by scripts/gpu_build.sh against
# that machine's PyTorch and the real MF frames copied beside it:
#   scripts/gpu_check.sh RTF MF_SAMPLES OUT [BUDGET_S] [PHASES]
# PHASES (default "env correct train infer python smoke extra") picks and orders the phases; a phase
# that would start after BUDGET_S seconds (default 420) is skipped and says so.
set -uo pipefail
rtf=$(realpath "$1")
mf=$(realpath "$2")
out=$(realpath -m "$3")
budget=${4:-420}
phases=${5:-env correct train infer python smoke extra}
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d)
mkdir -p "$out"
torch_dir=$(python3 -c 'import os, torch; print(os.path.dirname(torch.__file__))')
nvidia_libs=$(ls -d "$torch_dir"/../nvidia/*/lib 2>/dev/null | tr '\n' ':')
export LD_LIBRARY_PATH="$torch_dir/lib:$nvidia_libs${LD_LIBRARY_PATH:-}"
export PYTHONUNBUFFERED=1
status=0
say() { echo "[$(date -u +%T) +${SECONDS}s] $*"; }

phase_env() {
    {
        date -u
        nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
        python3 -c 'import torch; print("PyTorch", torch.__version__, "CUDA", torch.version.cuda,
"cuDNN", torch.backends.cudnn.version(), torch.cuda.get_device_name(0))'
        lscpu | grep -E '^(Model name|CPU\(s\))'
        "$rtf" --version
    } >"$out/env.txt" 2>&1
    cat "$out/env.txt"
}

# `rtf predict --logits` of MODEL with WEIGHTS on the real MF frames into WORK/PREFIX_RUN_PRECISION:
# RUN cpu, cuda or cuda_notf32 (NVIDIA_TF32_OVERRIDE=0), PRECISION plain or a fast path's.
logits_of() {
    local model=$1 weights=$2 prefix=$3 run=${4%%:*} precision=${4#*:} extra=()
    [ "$precision" = plain ] || extra=(--precision "$precision")
    env $([ "$run" = cuda_notf32 ] && echo NVIDIA_TF32_OVERRIDE=0) "$rtf" predict --model "$model" \
        --weights "$weights" --device "${run%_notf32}" "${extra[@]}" --logits \
        --out "$work/${prefix}_${run}_$precision" "$mf"/*.png >/dev/null
}

# One training step of MFNet from the published weights into WORK/NAME_RUN: RUN cpu, cuda or
# cuda_fp32 (NVIDIA_TF32_OVERRIDE=0 keeps cuDNN and cuBLAS off TF32: plain fp32 products).
one_step() {
    local name=$1 run=$2
    shift 2
    env $([ "$run" = cuda_fp32 ] && echo NVIDIA_TF32_OVERRIDE=0) "$rtf" train --model mfnet \
        --data "$work/step_data" --init "$mf/mfnet_final.safetensors" --epochs 1 --max-steps 1 \
        --batch-size 4 --no-shuffle --no-augment --seed 0 --device "${run%_fp32}" "$@" \
        --out "$work/${name}_$run" >"$work/${name}_$run.log" 2>&1 || { tail "$work/${name}_$run.log"; return 1; }
}

# The published MFNet on the two real MF frames: the GPU's labels against the CPU's (plain
# path on the CPU; plain, fast fp32, fp16 and bf16 on the GPU). Then one SGD step of MFNet from
# the published weights on the same batch, CPU against GPU (with TF32, libtorch's default, and
# without): the weight updates compared; one AdamW step likewise. Then CMX-B2's logits, GPU against CPU, with the weights
# of one GPU training step (it has no published ones).
phase_correct() {
    local variant
    for variant in cpu:plain cuda:plain cuda:fp32 cuda:fp16 cuda:bf16; do
        logits_of mfnet "$mf/mfnet_final.safetensors" mf "$variant" || return 1
    done
    "$rtf" synth --out "$work/step_data" --count 8 --size 320x256 --seed 3 >/dev/null || return 1
    for run in cpu cuda cuda_fp32; do
        one_step step "$run" || return 1
    done
    # rtf's AdamW in ATen's fused kernel (since 2026-11-29), on the GPU and the CPU.
    for run in cpu cuda_fp32; do
        one_step adamw "$run" --optimizer adamw --warmup-epochs 0 || return 1
    done
    "$rtf" train --model cmx-mit-b2 --data "$work/step_data" --epochs 1 --max-steps 1 --batch-size 2 \
        --no-shuffle --no-augment --seed 0 --device cuda --out "$work/cmx_init" >"$work/cmx_init.log" 2>&1 ||
        { tail "$work/cmx_init.log"; return 1; }
    for variant in cpu:plain cuda:plain cuda_notf32:plain cuda:fp32 cuda:fp16 cuda:bf16; do
        logits_of cmx-mit-b2 "$work/cmx_init/final.safetensors" cmx "$variant" || return 1
    done
    python3 "$here/../lab/gpu/gpu_correctness.py" "$work" "$mf/mfnet_final.safetensors" | tee "$out/correct.txt"
}

# CMX-B2 with its AdamW on both sides (gpu_bench.py's recipes); one more step of each counted.
phase_train() {
    python3 "$here/../lab/gpu/gpu_bench.py" train --rtf "$rtf" --models mfnet:8,rtfnet50:4,cmx-mit-b2:8 \
        --warmup 3 --iterations 10 --count-ops --json "$out/train.json"
}

# (`--diagnose mfnet`, rtf's fp32 with cuDNN's heuristics and on the plain path, was measured in
# the 2026-11-28 run and is left out to keep the second call short.)
phase_infer() {
    python3 "$here/../lab/gpu/gpu_bench.py" infer --rtf "$rtf" \
        --models mfnet,rtfnet50,rtfnet152:1,heatnet:1,cmx-mit-b2:1 --batches 1/8 --warmup 5 \
        --iterations 15 --json "$out/infer.json"
}

phase_smoke() {
    PYTHON=python3 bash "$here/gpu_smoke.sh" "$rtf" "$work/smoke" >"$out/smoke.log" 2>&1
    local rc=$?
    tail -n 25 "$out/smoke.log"
    return $rc
}

# The Python package (issue 60, item 4): the wheel scripts/gpu_build.sh wrote beside RTF,
# installed for this run only, `net(x)` on CUDA tensors against `rtf bench model`.
phase_python() {
    python3 -m pip install -q --no-index --no-deps --no-compile --target "$work/site" \
        "$(dirname "$rtf")"/wheel/rtf-*.whl || return 1
    PYTHONPATH="$work/site" python3 "$here/../lab/gpu/python_cuda.py" --rtf "$rtf" --frames "$mf" \
        --weights "$mf/mfnet_final.safetensors" --models mfnet,rtfnet50,cmx-mit-b2 --json "$out/python.json"
}

# Second priority: torch.compile, inference of two networks and MFNet's training step (where
# PyTorch's best might be compiled), and the CMX sizes around B2.
phase_extra() {
    python3 "$here/../lab/gpu/gpu_bench.py" infer --rtf "$rtf" --models mfnet:1,rtfnet50:1,cmx-mit-b0,cmx-mit-b4 \
        --compile mfnet,rtfnet50 --warmup 5 --iterations 20 --json "$out/extra.json"
    python3 "$here/../lab/gpu/gpu_bench.py" train --rtf "$rtf" --models mfnet:8 --compile mfnet \
        --precisions fp32,bf16 --warmup 3 --iterations 10 --json "$out/extra_train.json"
}

for name in $phases; do
    if [ "$SECONDS" -ge "$budget" ]; then
        say "skipped $name: ${SECONDS}s of the ${budget}s budget used"
        continue
    fi
    say "phase $name"
    if ! "phase_$name"; then
        say "phase $name FAILED"
        status=1
    fi
    ls "$out"/*.json >/dev/null 2>&1 &&
        python3 "$here/../lab/gpu/gpu_bench.py" table $(ls "$out"/{train,infer,extra,extra_train}.json 2>/dev/null) >"$out/tables.md"
done
say "done (status $status)"
cat "$out/tables.md" 2>/dev/null | grep -E '^\*\*|^- ' || true
exit $status
