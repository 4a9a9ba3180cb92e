#!/usr/bin/env bash
# The GPU figures the README leaves "not measured" (issue 22), in one run of about 10 minutes:
#   bash tools/gpu_check.sh OUT_DIR [MINUTES_OF_TRAINING]
# Needs a CUDA GPU that warp sees, and tron1cli's dependencies plus the `warp` extra importable
# (installed, or unpacked with `pip install --no-index --target DIR` and DIR on PYTHONPATH; the
# project itself is run from this checkout, so it needs no install). PARTS (default "compile tests
# bench train stairs") picks the parts and their order; two instances may share OUT_DIR (say
# tests in the background while compile runs). Writes into OUT_DIR:
#   gpu.txt                      nvidia-smi, versions
#   bench_compile.json           the first run on the machine: warp compiles its kernels
#   tests.log                    the warp tests on the GPU: parity with the CPU engine, the
#                                recorded step against per-kernel launches, a CLI training run
#   bench_<terrain>_<envs>.json  raw and env-core step rates (`tron1 bench --backend warp`),
#                                flat at each of ENVS; stairs with depth at the largest (part stairs)
#   bench_train_flat.json        a whole training iteration, learner on the GPU
#   train.log, eval/             `tron1 train --terrain flat` for MINUTES (default 3) on warp and
#                                the GPU, then `tron1 eval` of its checkpoint on flat ground
#   ptrain.log, peval/           the same on stairs with depth students (part perceptive, not in
#                                the default PARTS: MINUTES + 4 minutes more)
# Each step has its own time limit, and a failing step does not stop the later ones; steps.txt
# says how each ended. ENVS (default "1024 4096"), BENCH_STEPS (100) and DEVICE (cuda, the
# learner's) shrink it for a dry run on a machine without a GPU.
set -uo pipefail
out=${1:?usage: tools/gpu_check.sh OUT_DIR [MINUTES]}
minutes=${2:-3}
envs_list=${ENVS:-1024 4096}
steps=${BENCH_STEPS:-100}
device=${DEVICE:-cuda}
big=${envs_list##* }
parts=${PARTS:-compile tests bench train stairs}
mkdir -p "$out"
cd "$(dirname "$0")/.."
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
tron1=(python3 -m tron1cli)  # run from this checkout (timeout needs a program, not a function)
step() {  # step NAME SECONDS COMMAND...: run with a limit, say how it ended
  local name=$1 limit=$2 t0=$SECONDS
  shift 2
  timeout "$limit" "$@"
  echo "== $name: exit $? after $((SECONDS - t0)) s" | tee -a "$out/steps.txt"
}

[[ -s $out/gpu.txt ]] || { nvidia-smi; python3 -c "import torch, warp, mujoco, mujoco_warp; print('torch', \
torch.__version__, torch.cuda.is_available(), 'warp', warp.__version__, 'mujoco', mujoco.__version__)"; } \
  >"$out/gpu.txt" 2>&1
for part in $parts; do
  case $part in
  compile)  # the first run on a machine compiles warp's kernels (cached in ~/.cache/warp after)
    step "compile (first run, 64 envs)" 400 "${tron1[@]}" bench --backend warp --envs 64 --steps 5 \
      --rounds 1 --json >"$out/bench_compile.json"
    ;;
  tests)
    step tests 240 python3 -m pytest -q -m slow tests/test_physics_warp.py -p no:cacheprovider \
      >"$out/tests.log" 2>&1
    ;;
  bench)
    for envs in $envs_list; do
      step "bench flat $envs" 90 "${tron1[@]}" bench --backend warp --envs "$envs" --steps "$steps" \
        --json >"$out/bench_flat_$envs.json"
    done
    step "bench train flat" 150 "${tron1[@]}" bench --train --backend warp --device "$device" \
      --envs "$big" --rounds 2 --json >"$out/bench_train_flat.json"
    ;;
  train)
    step train $((minutes * 60 + 60)) "${tron1[@]}" train --terrain flat --backend warp \
      --envs "$big" --device "$device" --minutes "$minutes" --run-dir "$out/run" >"$out/train.log" 2>&1
    step eval 60 "${tron1[@]}" eval "$out/run/checkpoints/latest.pt" --terrain flat --envs 256 \
      --backend warp --out "$out/eval" >"$out/eval.log" 2>&1
    rm -rf "$out/run/checkpoints"  # the figures are in train.log and eval/; checkpoints stay behind
    ;;
  stairs)
    step "bench stairs $big" 240 "${tron1[@]}" bench --backend warp --envs "$big" --steps "$steps" \
      --terrain stairs --depth --json >"$out/bench_stairs_$big.json"
    ;;
  perceptive)  # the stairs preset (teachers and depth students) for MINUTES, then its eval
    step "train stairs" $((minutes * 60 + 120)) "${tron1[@]}" train --terrain stairs --backend warp \
      --envs "$big" --device "$device" --minutes "$minutes" --run-dir "$out/prun" >"$out/ptrain.log" 2>&1
    step "eval stairs" 120 "${tron1[@]}" eval "$out/prun/checkpoints/latest.pt" --terrain stairs \
      --envs 256 --backend warp --out "$out/peval" >"$out/peval.log" 2>&1
    rm -rf "$out/prun/checkpoints"
    ;;
  *) echo "gpu_check: unknown part $part (compile, tests, bench, train, stairs, perceptive)" >&2 ;;
  esac
done
