#!/usr/bin/env bash
# One GPU window as one call: install the carried wheels, self-test the update, measure the engine against the sync
# loop, then train paper-S for the rest of the window and bring back a packed checkpoint and its metrics.
#
#   bash benchmarks/gpu_window.sh             # on the GPU machine, from the repository root; $OUT comes back
#   bash benchmarks/gpu_window.sh --dry-run   # here: device cpu, tiny sizes, every step (tests/test_gpu_window.py)
#
# Steps, each logged to $OUT/window.txt:
#   1. setup     lab/gpu/device_train.sh's offline install of the wheels in .whl (lab/gpu/build_carry.sh builds them)
#   2. self-test benchmarks/learner_selftest.py: the graphed update equals the eager one after a few updates on
#                the same batches, and bf16 agrees with float32; a failure stops the window (`SELFTEST FAILED`)
#   3. engine    benchmarks/engine_speed.py --quick on the window's device: its RESULT line
#   4. train     CONFIG for the seconds left, then SIGTERM (a final checkpoint). A window continues the last one
#                on this machine: RUN's checkpoints with --resume, else the pack of the last window (RUN.pack,
#                git-ignored under runs/) with --init-from, else INIT_FROM, else from scratch, and says which.
#                CLIP_PACK (lab/gpu/clip_pack.py) is first unpacked beside itself, for a clip set too large to carry
#   5. pack      lab/gpu/pack.py: the checkpoint as float16 weights and reward states in parts of < 16 MiB, kept in
#                RUN.pack for the next window and copied to $OUT with metrics.csv (at most 8 files, 64 MiB)
#
# Env: OUT (required), WINDOW_S (570: the whole call, within a 9.5-minute call), INIT_FROM (a checkpoint, or
#      `pretrained`, that a first window warm-starts from), CLIP_PACK (data/clips/NAME.pack.npz: the clips the config
#      reads from data/clips/NAME, carried packed), CONFIG
#      (fbcpr/configs/gpu-paper-S.yaml; paper-S's optimiser state does not travel in 64 MiB, so a window on a new
#      machine continues from the packed weights, not the exact state), RUN (runs/window), PY (the Python to use).
set -euo pipefail
DRY=0
if [ "${1:-}" = "--dry-run" ]; then
  DRY=1
fi
start=$SECONDS
OUT=${OUT:?set OUT: the folder that comes back}
RUN=${RUN:-runs/window}
mkdir -p "$OUT" "$(dirname "$RUN")"
LOG=$OUT/window.txt
say() { echo "$*" | tee -a "$LOG"; }
left() { echo $((WINDOW_S - (SECONDS - start))); }

if [ "$DRY" = 1 ]; then
  WINDOW_S=${WINDOW_S:-150}
  DEVICE=cpu
  PY=${PY:-python3}
  CONFIG=${CONFIG:-$RUN.dry.yaml}
  BENCH=(--device cpu --preset tiny --envs 4 --collectors 1 --warmup 160 --steps 320 --rollout 40 --no-compile)
  SELFTEST=(--sizes tiny --updates 4)
  PACK_TAIL=30  # seconds kept for the pack at the end
  BENCH_SHARE=2  # the benchmark's share of what is left: a half here (its processes start slowly on a busy CPU)
  # the window's config at tiny sizes: the humanoid on the synthetic clips, a short warm-up, frequent checkpoints,
  # and a run of 1,200 env steps that ends on its own (the window's timeout only guards it)
  "$PY" - "$CONFIG" << 'EOF'
import sys
import yaml
cfg = {"model": {"preset": "tiny"}, "agent": {"batch_size": 32, "seq_length": 8},
       "env": {"name": "humanoid", "motions": "synthetic", "max_episode_steps": 100},
       "train": {"device": "cpu", "engine": "async", "collectors": 1, "num_envs": 4, "total_env_steps": 1200,
                 "warmup_steps": 80, "rollout_steps": 40, "updates_per_rollout": 4, "buffer_capacity": 20000,
                 "priority_every": 0, "eval_every": 0, "checkpoint_every": 400, "log_every": 200,
                 "reward_buffer_size": 200, "torch_threads": 1}}
yaml.safe_dump(cfg, open(sys.argv[1], "w"))
EOF
  say "gpu_window: DRY RUN (device cpu, tiny sizes) of every step, $WINDOW_S s"
else
  WINDOW_S=${WINDOW_S:-570}
  DEVICE=cuda
  CONFIG=${CONFIG:-fbcpr/configs/gpu-paper-S.yaml}
  PRESET=$("${PY:-python3}" -c "import sys, yaml; print(yaml.safe_load(open(sys.argv[1]))['model']['preset'])" "$CONFIG")
  BENCH=(--device cuda --quick --preset "$PRESET")
  SELFTEST=(--sizes small --updates 12)
  if [ "$PRESET" != small ]; then
    SELFTEST=(--sizes small "$PRESET" --updates 12)
  fi
  PACK_TAIL=60
  BENCH_SHARE=3
  say "gpu_window: $CONFIG on cuda, $WINDOW_S s"
  # 1. setup: the carried wheels and fbcpr, offline; the same Python as device_train.sh chose
  FBCPR_SETUP_ONLY=1 bash lab/gpu/device_train.sh "$CONFIG" "$RUN" >> "$LOG" 2>&1 || { say "SETUP FAILED (see above)"; exit 1; }
  PY=${PY:-$(if [ -x .devenv/bin/python ]; then echo .devenv/bin/python; else command -v python3; fi)}
fi
say "setup done at $((SECONDS - start)) s"

# 2. self-test: the graphed update against the eager one, and bf16 against float32 (benchmarks/learner_selftest.py)
if ! "$PY" benchmarks/learner_selftest.py --device "$DEVICE" "${SELFTEST[@]}" >> "$LOG" 2>&1; then
  grep "^SELFTEST" "$LOG" | tail -1 || say "SELFTEST FAILED: the self-test crashed (see above)"
  say "gpu_window: stopped at the self-test, $((SECONDS - start)) s"
  exit 2
fi
grep "^SELFTEST" "$LOG" | tail -1
say "self-test done at $((SECONDS - start)) s"

# 3. the engine against the sync loop
if timeout $(($(left) / BENCH_SHARE)) "$PY" benchmarks/engine_speed.py "${BENCH[@]}" >> "$LOG" 2> "$OUT/engine_speed.err"; then
  grep "^RESULT" "$LOG" | tail -1
else
  say "engine_speed: no RESULT (exit $?; its last lines:)"
  tail -5 "$OUT/engine_speed.err" | tee -a "$LOG"
fi
rm -f "$OUT/engine_speed.err"
say "engine benchmark done at $((SECONDS - start)) s"

# 4. train for what is left, continuing the last window on this machine
args=(--device "$DEVICE" --no-progress)
if [ -e "$RUN/checkpoints/latest" ]; then
  say "continuing: $RUN holds the last window's run, resumed exactly (--resume)"
  args+=(--resume)
elif compgen -G "$RUN.pack/*.tar.part*" > /dev/null; then
  rm -rf "$RUN.init"
  init=$("$PY" lab/gpu/pack.py unpack "$RUN.pack" "$RUN.init" | tail -1)
  say "continuing: the last window's run is gone, its pack is here: a new run from its weights ($init)"
  args+=(--init-from "$("$PY" -c "import sys; from pathlib import Path; print(sorted(Path(sys.argv[1]).glob('step_*'))[-1])" "$RUN.init")")
elif [ -n "${INIT_FROM:-}" ]; then
  say "no earlier window on this machine: a new run warm-started from $INIT_FROM (--init-from)"
  args+=(--init-from "$INIT_FROM")
else
  say "no earlier window on this machine (neither $RUN nor $RUN.pack): starting from scratch"
fi
if [ -n "${CLIP_PACK:-}" ]; then
  "$PY" lab/gpu/clip_pack.py unpack "$CLIP_PACK" "${CLIP_PACK%.pack.npz}" | tee -a "$LOG"
fi
train_s=$(($(left) - PACK_TAIL))
say "training for $train_s s: fbcpr train $CONFIG --out $RUN ${args[*]}"
set +e
PYTHONUNBUFFERED=1 timeout -s TERM -k 60 "$train_s" "$PY" -m fbcpr.cli.app train "$CONFIG" --out "$RUN" "${args[@]}" > "$RUN.log" 2>&1
code=$?
set -e
tail -3 "$RUN.log" | tee -a "$LOG"
if [ "$code" != 0 ] && [ "$code" != 124 ]; then
  say "training exited with code $code"
fi
say "training done at $((SECONDS - start)) s"

# 5. pack: kept for the next window, and sent back
if [ -e "$RUN/checkpoints/latest" ]; then
  "$PY" lab/gpu/pack.py pack "$RUN" "$RUN.pack" --parts 6 | tee -a "$LOG"
  cp "$RUN".pack/*.tar.part* "$OUT/"
fi
cp "$RUN/metrics.csv" "$OUT/" 2> /dev/null || say "no metrics.csv (the run logged nothing)"
say "gpu_window: done at $((SECONDS - start)) s; files back: $(ls "$OUT" | tr '\n' ' ')"
