#!/usr/bin/env bash
# Run ON THE DEVICE from the repository root, after device_train.sh, each call right after the previous one
# returns: waits SECONDS (default 540; less if training dies), then leaves in $OUT what a call can return (at most
# 8 files of 16 MiB, 64 MiB in all):
#   step_XXXXXXXXXX.tar.part<i>-of-<n>   the newest checkpoint, float16 weights (pack.py; n = 4 for paper-S)
#   metrics.csv                          the run's whole metrics log
#   status.txt                           trainer state, GPU use, packing report and the log tail
# With `stop` as third argument (the lease's last call), it stops the trainer first (SIGTERM: a final checkpoint
# at the next safe point) and packs that one. A SIGTERM to this script (the call's time limit) packs at once.
#   bash benchmarks/gpu_lease/device_wait.sh RUN_DIR [SECONDS] [stop]
set -uo pipefail
RUN=${1:?usage: device_wait.sh RUN_DIR [SECONDS] [stop]}
WAIT=${2:-540}
MODE=${3:-}
: "${OUT:?OUT must name the folder whose files come back}"
VPY=$(cat "$RUN.python" 2> /dev/null || command -v python3)
PID=$(cat "$RUN.pid" 2> /dev/null)
start=$SECONDS

alive() { [ -n "$PID" ] && kill -0 "$PID" 2> /dev/null; }
metric() { awk -F, -v k="$1" '$1 == k { v = $2 } END { print v }' "$RUN/metrics.csv" 2> /dev/null; }

collect() {
  trap - TERM
  if [ "$MODE" = stop ] && alive; then
    kill -TERM "$PID"
    for _ in $(seq 120); do
      alive || break
      sleep 1
    done
  fi
  mkdir -p "$OUT"
  cp "$RUN/metrics.csv" "$OUT/metrics.csv" 2> /dev/null
  local report
  report=$(
    echo "$(date -u +%FT%TZ): waited $((SECONDS - start)) s; trainer pid ${PID:-?} $(alive && echo running || echo 'not running')"
    echo "env_steps $(metric env_steps), updates $(metric updates), env steps/s $(metric env_steps_per_s)," \
         "fb_loss $(metric fb_loss), actor_loss $(metric actor_loss), disc_loss $(metric disc_loss)," \
         "tracking_emd $(metric eval/tracking_emd), tracking_success $(metric eval/tracking_success)"
    if command -v nvidia-smi > /dev/null; then
      nvidia-smi --query-gpu=utilization.gpu,memory.used,memory.total --format=csv,noheader
    fi
    "$VPY" benchmarks/gpu_lease/pack.py pack "$RUN" "$OUT" --parts 6 2>&1 | tail -n 5
  )
  { echo "$report"; echo "--- $RUN.log (tail)"; tail -n 100 "$RUN.log" 2> /dev/null; } > "$OUT/status.txt"
  echo "$report"
  ls -l "$OUT"
}
trap 'collect; exit 124' TERM

while [ $((SECONDS - start)) -lt "$WAIT" ] && alive; do
  sleep 5
done
alive || echo "trainer (pid ${PID:-?}) is not running: log tail"$'\n'"$(tail -n 30 "$RUN.log" 2> /dev/null)"
collect
