#!/usr/bin/env bash
# The device checks of one lent-GPU session, as one prepared script (docs/gpu.md, "On the project's lent GPU
# machine"). Run there from the project root, carrying .device/{whl-av,whl-train,fpsample,gl,on-device.sh,
# baseline}: `bash benchmarks/gpu_session.sh`. Each part has its own time limit and writes its log under
# $OUT (or outputs/gpu_session), so whatever finishes comes back even when a later part runs out of time.
# PARTS="collect tp_paper_b512_amp ..." runs only the parts named (collect is needed by every tp_* part).
#   1. a small Cube Handoff points view collected there (6 Stage episodes, ~2,560 frames: more than one batch
#      of 1024, which the timed loaders need, since they drop a partial batch);
#   2. issue 28: training step throughput, old (.device/baseline) vs new code, side by side, with GPU busy and
#      the batch fetch alone; the new code gathers its batches on the GPU (num_workers=0), and the *_host_gather
#      parts time it with BAVO_DEVICE_BATCHES=0 (gathered on the host, as before device-resident batches);
#   3. issue 30: `bavo-collect` / `bavo-eval` scaling from 2 to 16 workers on the 16-core machine, and the cost
#      of one frame with 2 and 16 processes rendering at once (render_contention);
#   4. issue 28: the paper preset's step with --policy.compile=true (new code only), then `lerobot-train` on
#      CUDA with LeRobot's default loader workers, a few steps, and with --num_workers=0 (device batches).
set -uo pipefail
OUT=${OUT:-outputs/gpu_session}
mkdir -p "$OUT"
source .device/on-device.sh
export OMP_NUM_THREADS=1
log() { echo "[gpu_session $(date +%T)] $*" | tee -a "$OUT/session.log"; }
part() {  # part NAME SECONDS CMD...: run CMD with a time limit, output to $OUT/NAME.log
    local name=$1 limit=$2; shift 2
    if [ -n "${PARTS:-}" ] && [[ " $PARTS " != *" $name "* ]]; then log "skip $name"; return; fi
    log "start $name (limit ${limit}s)"
    local t0=$SECONDS
    timeout "$limit" "$@" > "$OUT/$name.log" 2>&1
    log "end $name: exit $? after $((SECONDS - t0))s"
    tail -25 "$OUT/$name.log"
}
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$OUT/gpu.txt"
python -c 'import torch; print("torch", torch.__version__, "cuda", torch.version.cuda)' | tee -a "$OUT/gpu.txt"
python -c "import os; print('cores', os.cpu_count())" | tee -a "$OUT/gpu.txt"  # nproc would print OMP_NUM_THREADS

DATA=$(mktemp -d /tmp/gpu_bench.XXXXXX)/gpu_bench  # fresh each run (a machine may be reused)
part collect 90 bash -c "bavo-collect --task cube_handoff --condition stage --episodes 6 --repo-id local/gpu_bench \
    --root $DATA --workers 6 --no-progress && python -m lerobot_bavo.datasets.views --root $DATA --view points"
TP=(python benchmarks/train_throughput.py --device cuda --threads 8 --root ${DATA}_points
    --repo-id local/gpu_bench_points --baseline-dir .device/baseline --steps 15 --warmup 5 --load-batches 20)
part tp_paper_b512_amp 100 "${TP[@]}" --preset paper --batch 512 --use-amp
part tp_paper_b256_amp 80 "${TP[@]}" --preset paper --batch 256 --use-amp
part tp_cpu_fast_b512 60 "${TP[@]}" --preset cpu_fast --batch 512
part tp_cpu_fast_b256 60 "${TP[@]}" --preset cpu_fast --batch 256
part tp_paper_b512_amp_host_gather 100 env BAVO_DEVICE_BATCHES=0 "${TP[@]}" --preset paper --batch 512 --use-amp
part tp_cpu_fast_b512_host_gather 60 env BAVO_DEVICE_BATCHES=0 "${TP[@]}" --preset cpu_fast --batch 512
part scale_workers 170 python benchmarks/scale_workers.py --workers 2,16 --episodes ${SCALE_EPISODES:-40} --job both \
    --json "$OUT/scale_workers.json"
# issue 30: is one frame slower when 16 processes render on the GPU at once? (docs/results/costs.md)
part render_contention 150 python benchmarks/render_contention.py --procs 2,16
# the same and the scaling with every worker rendering in software on its own core (Mesa's llvmpipe, carried as
# .device/mesa by `bash benchmarks/mesa_egl.sh prepare`, ~48 MiB: a call of its own after the installs)
part render_contention_mesa 150 bash -c "source benchmarks/mesa_egl.sh use && \
    python benchmarks/render_contention.py --procs 2,16"
# (2026-11-30: 45 + 271 s collecting, 22 + 152 s evaluating with 16 and 2 workers: ~8.5 min with start-up)
part scale_workers_mesa 540 bash -c "source benchmarks/mesa_egl.sh use && python benchmarks/scale_workers.py \
    --workers 16,2 --episodes ${SCALE_EPISODES:-48} --job both --json $OUT/scale_workers_mesa.json"
part tp_paper_b512_amp_compile 300 "${TP[@]}" --preset paper --batch 512 --use-amp \
    --new-policy-arg compile=true
# CUDA graphs (the GPU-busy target) and the small preset compiled (its samples/s target): timed 2026-11-27
part tp_paper_b512_amp_compile_graphs 300 "${TP[@]}" --preset paper --batch 512 --use-amp \
    --new-policy-arg compile=true --new-policy-arg compile_mode=reduce-overhead
part tp_cpu_fast_b512_compile 200 "${TP[@]}" --preset cpu_fast --batch 512 --new-policy-arg compile=true
part tp_cpu_fast_b512_compile_graphs 200 "${TP[@]}" --preset cpu_fast --batch 512 --new-policy-arg compile=true \
    --new-policy-arg compile_mode=reduce-overhead
part tp_cpu_fast_b1024_compile_graphs 300 "${TP[@]}" --preset cpu_fast --batch 1024 --new-policy-arg compile=true \
    --new-policy-arg compile_mode=reduce-overhead
# the graphed step's losses and gradients against eager (pytest's wheels carried in .device/whl-train: docs/gpu.md)
part graphs_check 400 python -m pytest -m slow -q -p no:cacheprovider tests/test_training_step.py -k cuda_graphs
# issue 28's CUDA data-path tests: batches gathered on the GPU equal LeRobot's items collated (every view, with
# and without delta_timestamps, an episode subset), and lerobot-train on CUDA gathers them there
part cuda_tests 300 python -m pytest -q -p no:cacheprovider tests/test_fast_dataset.py tests/test_training_defaults.py \
    -k cuda
# the recipe's compile setting end to end: lerobot-train with CUDA graphs, a checkpoint saved at the end
part train_graphs 240 lerobot-train --policy.type=afar --policy.preset=cpu_fast --policy.device=cuda \
    --policy.push_to_hub=false --dataset.repo_id=local/gpu_bench_points --dataset.root=${DATA}_points \
    --num_workers=0 --batch_size=512 --steps=40 --log_freq=10 --save_freq=40 --output_dir=/tmp/train_graphs \
    --policy.compile=true --policy.compile_mode=reduce-overhead --wandb.enable=false
# docs/gpu.md's recipe command as written (paper preset, bf16, batch 512, compiled with CUDA graphs), five steps
# (5 x 512 of the view's ~2,560 frames: no partial batch), a checkpoint saved, then loaded back and run once
# (no video: the GPU image has imageio without its ffmpeg plugin, a declared dependency pip would install)
part recipe_check 450 bash -c "rm -rf /tmp/recipe_check /tmp/recipe_check_eval && lerobot-train --policy.type=afar --policy.preset=paper --policy.device=cuda \
    --policy.use_amp=true --policy.push_to_hub=false --dataset.repo_id=local/gpu_bench_points \
    --dataset.root=${DATA}_points --batch_size=512 --steps=5 --policy.optimizer_lr=2.8e-4 \
    --policy.scheduler_warmup_steps=500 --num_workers=0 --policy.compile=true \
    --policy.compile_mode=reduce-overhead --save_freq=5 --log_freq=1 --seed=1000 \
    --output_dir=/tmp/recipe_check --wandb.enable=false && bavo-eval --policy \
    /tmp/recipe_check/checkpoints/last/pretrained_model --tasks cube_handoff --conditions stage --episodes 1 \
    --seed 1000 --workers 1 --videos 0 --output-dir /tmp/recipe_check_eval"
part train_defaults 120 lerobot-train --policy.type=afar --policy.preset=cpu_fast --policy.device=cuda \
    --policy.push_to_hub=false --dataset.repo_id=local/gpu_bench_points --dataset.root=${DATA}_points \
    --steps=20 --log_freq=5 --save_checkpoint=false --output_dir=/tmp/train_defaults --wandb.enable=false
part train_device_batches 120 lerobot-train --policy.type=afar --policy.preset=cpu_fast --policy.device=cuda \
    --policy.push_to_hub=false --dataset.repo_id=local/gpu_bench_points --dataset.root=${DATA}_points \
    --num_workers=0 --steps=20 --log_freq=5 --save_checkpoint=false --output_dir=/tmp/train_device_batches \
    --wandb.enable=false
log done
