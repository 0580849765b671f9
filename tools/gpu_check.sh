#!/bin/bash
# GPU checks of demo, one script for a machine with a CUDA GPU: the CUDA tests, bf16 training of state BC
# (pick, collected here) and of image BC, diffusion and ACT on a gym-aloha store (ALOHA_STORE, skipped when
# absent), a 1-GPU torchrun run over NCCL, bench train/infer on cuda and image BC on 16 CPU cores. Results:
# $OUT/log.txt and $OUT/res.tgz.NN (the runs without train_state.pt, the bench JSON); evaluate the runs
# on a CPU afterwards (demo eval RUN --device cpu). Where the GPU machine lacks packages, wheels in .whl/
# are installed first. A dry run on a CPU: QUICK=1 DEVICE=cpu PY=.venv/bin/python tools/gpu_check.sh
set -u
export PYTHONUNBUFFERED=1
DEVICE=${DEVICE:-cuda}; QUICK=${QUICK:-0}; OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
R=/tmp/res; rm -rf $R; mkdir -p $R/runs
exec > >(tee -a "$OUT/log.txt") 2>&1
t0=$(date +%s); stamp() { echo "== [$(( $(date +%s) - t0 )) s] $*"; }
ALOHA_STORE=${ALOHA_STORE:-.gpu/tc50.zarr}   # demo bench suite aloha's transfer-cube store (50 demos, 128x96)
if [ "$DEVICE" = cuda ] && [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
  mkdir -p /tmp/pkg && ln -sfn "$PWD" /tmp/pkg/demo
  export PYTHONPATH=/tmp/pkg:/tmp/site PY=python3
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
  (MUJOCO_GL=egl python3 -c "import mujoco; c = mujoco.GLContext(64, 64); c.make_current(); print('EGL ok')" && echo egl > /tmp/gl) || echo "no EGL"
  [ -f /tmp/gl ] && export MUJOCO_GL=egl
else
  PY=${PY:-python3}
fi
$PY -c "import torch, mujoco, demo.cli.main; print('torch', torch.__version__, 'mujoco', mujoco.__version__, 'cuda', torch.cuda.is_available())"
D="$PY -m demo"
S() { if [ "$QUICK" = 1 ]; then echo "--steps 20"; else echo "$@"; fi; }   # steps (tiny in a dry run)
TL=${TL:-330}   # seconds each background training may run (its policy is checkpointed every 30 s)

stamp "pick state store (100 scripted demos, seed 0)"
$D collect --task pick --episodes $([ "$QUICK" = 1 ] && echo 4 || echo 100) --seed 0 --out $R/pick.zarr --workers 4 | tail -4

stamp "background trainings on $DEVICE (bf16 autocast), each at most $TL s"
train() { name=$1; shift; ( s=$(date +%s); timeout $TL $D train "$@" --out $R/runs/$name --device $DEVICE --threads 2 \
          --checkpoint-every 30 --json $R/runs/$name.json > $R/runs/$name.log 2>&1; rc=$?; echo "$name rc=$rc wall $(( $(date +%s) - s )) s" ) & PIDS+=($!); }
PIDS=()
train pick_bc $R/pick.zarr $(S)
if [ -d "$ALOHA_STORE" ]; then
  train tc_act "$ALOHA_STORE" --algo act $(S)
  train tc_act_b256 "$ALOHA_STORE" --algo act --batch-size 256 $(S)
  train tc_diffusion "$ALOHA_STORE" --algo diffusion $(S)
  train tc_bc1 "$ALOHA_STORE" --chunk 1 --no-ensemble $(S)
fi

stamp "CUDA tests (pytest), beside the trainings"
if [ "$DEVICE" = cuda ]; then
  $PY -m pytest -q -p no:cacheprovider tests/policies/test_device.py tests/training/test_distributed.py -k "cuda or nccl or device" 2>&1 | tail -15
  stamp "1-GPU torchrun (NCCL): pick BC, 1000 steps"
  OMP_NUM_THREADS=2 timeout 200 $PY -m torch.distributed.run --standalone --nproc-per-node=1 -m demo train $R/pick.zarr \
    --out $R/runs/ddp --device $DEVICE --steps 1000 --json $R/runs/ddp.json 2>&1 | tail -3
  $PY -c "import json; print('data_parallel', json.load(open('$R/runs/ddp/run.json'))['data_parallel'])"
fi
wait "${PIDS[@]}"   # not a bare wait: it would wait for the tee of the log too
stamp "trainings done"; tail -n 2 $R/runs/*.log

stamp "benchmarks (nothing else running): $DEVICE, and image BC on this machine's 16 CPU cores"
SEC=$([ "$QUICK" = 1 ] && echo 2 || echo 8)
B="--seconds $SEC --device $DEVICE"
if [ "$QUICK" != 1 ]; then
  $D bench train --images --frames 4000 $B --json $R/bench_train_images_$DEVICE.json | tail -10
  $D bench train --images --frames 4000 --encoder resnet18 $B --json $R/bench_train_resnet18_$DEVICE.json | tail -10
  $D bench train $B --json $R/bench_train_state_$DEVICE.json | tail -8
  $D bench infer $B --json $R/bench_infer_mlp_$DEVICE.json | tail -8
  $D bench infer --large $B --json $R/bench_infer_unet_$DEVICE.json | tail -8
fi
$D bench train --images --frames 4000 --seconds $SEC --device cpu --threads 16 --json $R/bench_train_images_cpu16.json | tail -10
stamp "pack"
rm -f $R/runs/*/train_state.pt; rm -rf $R/pick.zarr
tar -C $R -czf /tmp/res.tgz . && split -b 15M -d /tmp/res.tgz "$OUT/res.tgz." && ls -la "$OUT"
stamp end
