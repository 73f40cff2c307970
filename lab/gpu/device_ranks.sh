#!/usr/bin/env bash
# Run ON THE DEVICE, after the install of device_train.sh: data-parallel training with N torchrun processes on the
# cloud GPU(s), a short run in the foreground, to show the multi-process GPU path starts and keeps its replicas
# identical (the trainer checks them bit for bit at start and at its final checkpoint).
#   FBCPR_SETUP_ONLY=1 bash lab/gpu/device_train.sh fbcpr/configs/gpu.yaml runs/x   # install only
#   bash lab/gpu/device_ranks.sh fbcpr/configs/gpu.yaml runs/ranks [N]
# N (default 2) processes; NCCL needs one GPU per process, so with fewer GPUs than N they share them over gloo
# (train.dist_backend: gloo, gradients reduced through host memory), and a one-rank NCCL group on GPU 0 is started
# on its own to show the NCCL library initialises and all-reduces there. Env: FBCPR_STEPS (total env steps,
# default 20000: the warm-up is shortened to a quarter of it), FBCPR_DEVICE (cuda; cpu to try it here), PYTHON. Puts the log, metrics.csv and summary.json
# into $OUT.
set -euo pipefail
CONFIG=${1:?usage: device_ranks.sh CONFIG RUN_DIR [N]}
RUN=${2:?usage: device_ranks.sh CONFIG RUN_DIR [N]}
N=${3:-2}
STEPS=${FBCPR_STEPS:-20000}
VPY=${PYTHON:-$( [ -x .devenv/bin/python ] && echo .devenv/bin/python || command -v python3 )}
OUT=${OUT:-$RUN.out}
mkdir -p "$OUT" "$(dirname "$RUN")"
DEVICE=${FBCPR_DEVICE:-cuda}
gpus=$("$VPY" -c "import torch; print(torch.cuda.device_count())")
backend=nccl
[ "$gpus" -ge "$N" ] && [ "$DEVICE" = cuda ] || backend=gloo
echo "$N processes on $gpus GPU(s): train.dist_backend $backend" | tee "$OUT/ranks.txt"

if [ "$backend" = gloo ] && [ "$gpus" -ge 1 ]; then  # NCCL itself, one rank on GPU 0
  MASTER_ADDR=127.0.0.1 MASTER_PORT=29511 "$VPY" - << 'EOF' 2>&1 | tee -a "$OUT/ranks.txt"
import torch, torch.distributed as dist
torch.cuda.set_device(0)
dist.init_process_group("nccl", rank=0, world_size=1)
t = torch.ones(4, device="cuda")
dist.all_reduce(t)
print(f"NCCL {'.'.join(map(str, torch.cuda.nccl.version()))}: a one-rank group on {torch.cuda.get_device_name(0)} "
      f"all-reduced {t.tolist()}")
dist.destroy_process_group()
EOF
fi

"$VPY" - "$CONFIG" "$RUN.yaml" "$N" "$STEPS" "$backend" << 'EOF'
import sys
from fbcpr.core.config import dump_config, load_config
src, dst, n, steps, backend = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
cfg = load_config(src)
tc = cfg.train
tc.num_envs = max(1, tc.num_envs // n)  # the same envs in all as one process of the config
tc.total_env_steps, tc.warmup_steps = steps, steps // 4
tc.checkpoint_every, tc.save_buffer, tc.dist_backend, tc.dist_timeout_s = 0, False, backend, 300
tc.log_every = max(1000, steps // 10)
open(dst, "w").write(dump_config(cfg))
print(f"{dst}: {tc.num_envs} envs per rank, {steps} env steps ({tc.warmup_steps} warm-up)")
EOF
start=$SECONDS
set +e
PYTHONUNBUFFERED=1 "$VPY" -m torch.distributed.run --standalone --nproc_per_node="$N" -m fbcpr train "$RUN.yaml" \
  --out "$RUN" --device "$DEVICE" --no-progress > "$RUN.log" 2>&1
rc=$?
set -e
echo "torchrun exit $rc after $((SECONDS - start)) s" | tee -a "$OUT/ranks.txt"
tail -n 30 "$RUN.log" | tee -a "$OUT/ranks.txt"
nvidia-smi --query-gpu=name,memory.used,memory.total --format=csv 2> /dev/null | tee -a "$OUT/ranks.txt" || true
cp "$RUN.log" "$OUT/"
for f in metrics.csv summary.json; do
  [ -f "$RUN/$f" ] && cp "$RUN/$f" "$OUT/"
done
exit "$rc"
