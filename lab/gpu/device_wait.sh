#!/usr/bin/env bash
# Run ON THE DEVICE from the repository root, after device_train.sh, each call right after the previous one
# returns: waits SECONDS (default 540; less if training dies), then leaves in $OUT what a call can return (at most
# 8 files of 16 MiB, 64 MiB in all):
#   step_XXXXXXXXXX.tar.part<i>-of-<n>   the newest checkpoint, float16 weights (pack.py; n = 4 for paper-S)
#   metrics.csv                          the run's whole metrics log
#   status.txt                           trainer state, GPU use, packing report and the log tail
# Several seeds (device_train.sh with FBCPR_SEEDS, listed in RUN_DIR.runs): the same per run in $OUT/<run name>/,
# the checkpoint in one part (16 MiB: the small networks and ~40k reward states), and one status.txt for all.
# With `stop` as third argument (the GPU run's last call), it stops the trainers first (SIGTERM: a final checkpoint
# at the next safe point) and packs those. A SIGTERM to this script (the call's time limit) packs at once.
#   bash lab/gpu/device_wait.sh RUN_DIR [SECONDS] [stop]
set -uo pipefail
RUN=${1:?usage: device_wait.sh RUN_DIR [SECONDS] [stop]}
WAIT=${2:-540}
MODE=${3:-}
: "${OUT:?OUT must name the folder whose files come back}"
RUNS=("$RUN")
if [ -f "$RUN.runs" ]; then
  mapfile -t RUNS < "$RUN.runs"
fi
VPY=$(cat "${RUNS[0]}.python" 2> /dev/null || command -v python3)
start=$SECONDS

pid() { cat "$1.pid" 2> /dev/null; }
alive() { local p; p=$(pid "$1"); [ -n "$p" ] && kill -0 "$p" 2> /dev/null; }
any_alive() { for r in "${RUNS[@]}"; do alive "$r" && return 0; done; return 1; }
metric() { awk -F, -v k="$1" '$1 == k { v = $2 } END { print v }' "$2/metrics.csv" 2> /dev/null; }

collect() {
  trap - TERM
  if [ "$MODE" = stop ]; then
    for r in "${RUNS[@]}"; do
      alive "$r" && kill -TERM "$(pid "$r")"
    done
    for _ in $(seq 120); do
      any_alive || break
      sleep 1
    done
  fi
  mkdir -p "$OUT"
  local report dest parts=6
  [ "${#RUNS[@]}" -gt 1 ] && parts=1
  report=$(
    echo "$(date -u +%FT%TZ): waited $((SECONDS - start)) s"
    for r in "${RUNS[@]}"; do
      dest=$OUT
      [ "${#RUNS[@]}" -gt 1 ] && dest=$OUT/$(basename "$r")
      mkdir -p "$dest"
      cp "$r/metrics.csv" "$dest/metrics.csv" 2> /dev/null
      echo "$r: trainer pid $(pid "$r") $(alive "$r" && echo running || echo 'not running')"
      echo "env_steps $(metric env_steps "$r"), updates $(metric updates "$r"), env steps/s" \
           "$(metric env_steps_per_s "$r"), fb_loss $(metric fb_loss "$r"), actor_loss $(metric actor_loss "$r")," \
           "disc_loss $(metric disc_loss "$r"), tracking_emd $(metric eval/tracking_emd "$r")," \
           "tracking_success $(metric eval/tracking_success "$r")"
      "$VPY" lab/gpu/pack.py pack "$r" "$dest" --parts "$parts" 2>&1 | tail -n 5
    done
    if command -v nvidia-smi > /dev/null; then
      nvidia-smi --query-gpu=utilization.gpu,memory.used,memory.total --format=csv,noheader
    fi
  )
  {
    echo "$report"
    for r in "${RUNS[@]}"; do
      echo "--- $r.log (tail)"
      tail -n $((100 / ${#RUNS[@]})) "$r.log" 2> /dev/null
    done
  } > "$OUT/status.txt"
  echo "$report"
  ls -lR "$OUT"
}
trap 'collect; exit 124' TERM

while [ $((SECONDS - start)) -lt "$WAIT" ] && any_alive; do
  sleep 5
done
for r in "${RUNS[@]}"; do
  alive "$r" || echo "trainer of $r (pid $(pid "$r")) is not running: log tail"$'\n'"$(tail -n 30 "$r.log" 2> /dev/null)"
done
collect
