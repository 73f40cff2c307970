#!/usr/bin/env bash
# Run ON THE DEVICE from the repository root (first call of a GPU run): install the carried wheels and fbcpr offline
# beside the image's packages (torch with CUDA, numpy, ...), show the GPU, start training detached (setsid +
# nohup, log in RUN_DIR.log, pid in RUN_DIR.pid) and return once it is updating, or has died.
#   bash lab/gpu/device_train.sh CONFIG RUN_DIR
# Env: FBCPR_DEVICE (cuda), FBCPR_STEPS (override train.total_env_steps), FBCPR_INIT_FROM (a checkpoint to
#      warm-start from: `pretrained` continues the shipped model), FBCPR_SEEDS (e.g. "0 1 2": one trainer per
#      training seed, at most 3, sharing the GPU and splitting the cores; run dirs RUN_DIR-s<seed>, listed in
#      RUN_DIR.runs for device_wait.sh), FBCPR_CUDA_GRAPH=1 (agent.cuda_graph: the update captured in a CUDA
#      graph), FBCPR_HOST_BATCHES=1 (train.device_buffer false: batches drawn on the host, should the device draw
#      fail), FBCPR_SETUP_ONLY=1 (install and check only), WHEELS (.whl),
#      WATCH_SECONDS (180: how long to watch the start), PYTHON (python3).
set -euo pipefail
CONFIG=${1:?usage: device_train.sh CONFIG RUN_DIR}
RUN=${2:?usage: device_train.sh CONFIG RUN_DIR}
WHEELS=${WHEELS:-.whl}
WATCH_SECONDS=${WATCH_SECONDS:-180}
PYTHON=${PYTHON:-$(command -v python3 || command -v python)}
start=$SECONDS
read -ra SEEDS <<< "${FBCPR_SEEDS:-}"
if [ "${#SEEDS[@]}" -gt 3 ]; then
  echo "FBCPR_SEEDS: at most 3 seeds (a call returns 8 files: a part and a metrics.csv per run, and status.txt)" >&2
  exit 1
fi
RUNS=("$RUN")
if [ "${#SEEDS[@]}" -gt 0 ]; then
  RUNS=()
  for s in "${SEEDS[@]}"; do
    RUNS+=("$RUN-s$s")
  done
fi
if [ -z "${FBCPR_SETUP_ONLY:-}" ]; then
  for r in "$RUN" "${RUNS[@]}"; do
    if [ -e "$r" ]; then
      echo "$r exists already: give a new run dir" >&2
      exit 1
    fi
  done
fi

# A venv over the image's Python keeps its packages visible and untouched; --without-pip needs no ensurepip: the
# image's pip, run by the venv's interpreter, installs into the venv. An image whose Python is a venv already is
# installed into directly (a venv on top would not see its packages). --no-deps: exactly the carried wheels.
if "$PYTHON" -c 'import sys; sys.exit(sys.prefix == sys.base_prefix)'; then
  VPY=$PYTHON
else
  VPY=.devenv/bin/python
  [ -x "$VPY" ] || "$PYTHON" -m venv --system-site-packages --without-pip .devenv
fi
# mujoco and gymnasium at the versions pinned here (the physics that evaluation here uses); their other
# dependencies only where the image lacks them (it has cloudpickle, say), so no package of the image changes.
"$VPY" - "$WHEELS/requirements.txt" > "$WHEELS/install.txt" << 'EOF'
import importlib.metadata as md, sys
for line in open(sys.argv[1]).read().split():
    name = line.split("==")[0]
    try:
        have = md.version(name)
    except md.PackageNotFoundError:
        have = None
    if name in ("mujoco", "mujoco-core", "gymnasium") or have is None:
        print(line)
    else:
        print(f"{name} {have} is in the image already", file=sys.stderr)
EOF
"$VPY" -m pip install -q --no-index --find-links "$WHEELS" --no-deps -r "$WHEELS/install.txt"
"$VPY" -m pip install -q --no-index --find-links "$WHEELS" --no-deps -e .
echo "installed in $((SECONDS - start)) s"
if command -v nvidia-smi > /dev/null; then
  nvidia-smi
fi
"$VPY" - << 'EOF'
import importlib.util, os, platform
import gymnasium, mujoco, numpy, torch
import fbcpr.cli.app, fbcpr.train.trainer  # the whole training path imports
print(f"python {platform.python_version()}, torch {torch.__version__} (CUDA {torch.version.cuda}), mujoco "
      f"{mujoco.__version__}, gymnasium {gymnasium.__version__}, numpy {numpy.__version__}, {os.cpu_count()} CPUs")
if torch.cuda.is_available():
    p = torch.cuda.get_device_properties(0)
    print(f"cuda: {torch.cuda.device_count()} device(s), {p.name}, {p.total_memory / 2**30:.0f} GiB, "
          f"capability {p.major}.{p.minor}")
else:
    print("cuda: not available")
absent = [m for m in ("ot", "scipy", "tensorboard", "dm_control", "mink") if importlib.util.find_spec(m) is None]
print(f"optional packages absent: {', '.join(absent) or 'none'} (EMD: POT, else scipy's assignment, else no "
      f"priority refresh; tensorboard: else metrics.csv only)")
EOF
if [ -n "${FBCPR_SETUP_ONLY:-}" ]; then
  exit 0
fi
mkdir -p "$(dirname "$RUN")"
args=(--device "${FBCPR_DEVICE:-cuda}" --no-progress)
if [ -n "${FBCPR_STEPS:-}" ]; then
  args+=(--steps "$FBCPR_STEPS")
fi
if [ -n "${FBCPR_INIT_FROM:-}" ]; then
  args+=(--init-from "$FBCPR_INIT_FROM")
fi
detach=(setsid nohup)  # detached from this shell: the trainer outlives this call
command -v setsid > /dev/null || detach=(nohup)
printf '%s\n' "${RUNS[@]}" > "$RUN.runs"  # for device_wait.sh
for i in "${!RUNS[@]}"; do
  r=${RUNS[$i]}
  cfg=$CONFIG
  seed=${SEEDS[$i]:-}
  if [ -n "$seed" ] || [ -n "${FBCPR_CUDA_GRAPH:-}" ] || [ -n "${FBCPR_HOST_BATCHES:-}" ]; then
    # the config with this run's seed and an equal share of the cores, and/or the captured update, and/or host
    # batches, beside it so that its relative paths hold
    cfg="$(dirname "$CONFIG")/.$(basename "$CONFIG" .yaml)${seed:+-s$seed}${FBCPR_CUDA_GRAPH:+-graph}${FBCPR_HOST_BATCHES:+-host}.yaml"
    "$VPY" - "$CONFIG" "$cfg" "$seed" "${#SEEDS[@]}" "${FBCPR_CUDA_GRAPH:-}" "${FBCPR_HOST_BATCHES:-}" << 'EOF'
import os, sys, yaml
src, dst, seed, n, graph, host = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5], sys.argv[6]
cfg = yaml.safe_load(open(src))
if seed:
    share = max(1, (os.cpu_count() or 1) // n)
    cfg.setdefault("train", {}).update(seed=int(seed), torch_threads=share, env_threads=share)
    print(f"{dst}: train.seed {seed}, {share} torch and {share} MuJoCo threads")
if graph:
    cfg.setdefault("agent", {})["cuda_graph"] = True
    print(f"{dst}: agent.cuda_graph true")
if host:
    cfg.setdefault("train", {})["device_buffer"] = False
    print(f"{dst}: train.device_buffer false")
yaml.safe_dump(cfg, open(dst, "w"), sort_keys=False)
EOF
  fi
  echo "$VPY" > "$r.python"  # for device_wait.sh
  PYTHONUNBUFFERED=1 "${detach[@]}" "$VPY" -m fbcpr.cli.app train "$cfg" --out "$r" "${args[@]}" > "$r.log" 2>&1 < /dev/null &
  echo "$!" > "$r.pid"
  echo "training: pid $!, log $r.log, started $((SECONDS - start)) s after this script"
done

# Watch the start: the first gradient updates come after the random warm-up.
metric() { awk -F, -v k="$1" '$1 == k { v = $2 } END { print v }' "$2/metrics.csv" 2>/dev/null; }
watched=0
while [ "$watched" -lt "$WATCH_SECONDS" ]; do
  sleep 5
  watched=$((watched + 5))
  updating=0
  for r in "${RUNS[@]}"; do
    if ! kill -0 "$(cat "$r.pid")" 2> /dev/null; then
      if [ -f "$r/summary.json" ]; then  # a short run (FBCPR_STEPS) that finished
        updating=$((updating + 1))
        continue
      fi
      echo "training in $r exited after ${watched} s; log tail:" >&2
      tail -n 40 "$r.log" >&2
      exit 1
    fi
    if awk -v u="$(metric updates "$r")" 'BEGIN { exit !(u + 0 > 0) }'; then
      updating=$((updating + 1))
    fi
  done
  if [ "$updating" -eq "${#RUNS[@]}" ]; then
    break
  fi
done
for r in "${RUNS[@]}"; do
  echo "$r after ${watched} s: env_steps $(metric env_steps "$r"), updates $(metric updates "$r"), env steps/s" \
       "$(metric env_steps_per_s "$r"), fb_loss $(metric fb_loss "$r"), actor_loss $(metric actor_loss "$r")"
  tail -n 20 "$r.log"
done
if command -v nvidia-smi > /dev/null; then
  nvidia-smi --query-gpu=utilization.gpu,memory.used,memory.total --format=csv
fi
echo "running: now call device_wait.sh $RUN at once (the machine is released 30 s after a call returns)"
