#!/usr/bin/env bash
# Run HERE (not on the device), with the project's venv active: fills the git-ignored paths a GPU run carries.
#   .whl/                  manylinux wheels, for the device's Python, of what its image lacks: mujoco (the
#                          bindings in mujoco-core; the meta package's viewer and OpenGL deps are left out),
#                          gymnasium and its deps, setuptools (builds fbcpr offline), requirements.txt (what to install)
#   data/clips/deepmimic/  the DeepMimic clips (`fbcpr motions import`, cached after the first time); or, with
#                          CLIP_PACK=data/clips/NAME.pack.npz, the clips of data/clips/NAME packed as one file
#                          (lab/gpu/clip_pack.py; gpu_window.sh unpacks it there), for a set too large to carry
# Then prints what the GPU run copies (tree + carry) and fails above MAX_MIB.
# Env: DEVICE_PY (3.12), WHEELS (.whl), SHARED (../shared), MAX_MIB (60), CLIPS (data/clips/deepmimic), SYNTHETIC.
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
DEVICE_PY=${DEVICE_PY:-3.12}
WHEELS=${WHEELS:-.whl}
SHARED=${SHARED:-../shared}
MAX_MIB=${MAX_MIB:-60}
CLIPS=${CLIPS:-data/clips/deepmimic}  # data/clips/mixed: the shipped model's clips (with SYNTHETIC=1)
command -v fbcpr > /dev/null || { echo "activate the project's venv first (fbcpr not found)" >&2; exit 1; }

# The versions installed here, so that a model trained there is evaluated here on the same physics.
version() { python -c "import importlib.metadata as m; print(m.version('$1'))"; }
MUJOCO=$(version mujoco)
GYMNASIUM=$(version gymnasium)

abi=cp${DEVICE_PY/./}
target=(--only-binary=:all: --python-version "$DEVICE_PY" --implementation cp --abi "$abi"
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)
rm -rf "$WHEELS"
mkdir -p "$WHEELS"
# mujoco-core and gymnasium with their dependencies; the `mujoco` package itself without its own (mujoco-studio,
# glfw, PyOpenGL: 16 MB of viewer and rendering that `import mujoco` treats as optional).
pip download -q "${target[@]}" -d "$WHEELS" "mujoco-core==$MUJOCO" "gymnasium==$GYMNASIUM" "setuptools>=68"
pip download -q "${target[@]}" --no-deps -d "$WHEELS" "mujoco==$MUJOCO"
rm -f "$WHEELS"/numpy-*.whl "$WHEELS"/typing_extensions-*.whl  # in the image already (torch needs both)
# name==version of every wheel but setuptools: device_train.sh installs exactly these, with --no-deps.
for whl in "$WHEELS"/*.whl; do
  base=$(basename "$whl")
  name=${base%%-*}
  rest=${base#*-}
  [ "$name" = setuptools ] || echo "${name//_/-}==${rest%%-*}"
done > "$WHEELS/requirements.txt"
echo "wheels for Python $DEVICE_PY ($abi) in $WHEELS:"
sed 's/^/  /' "$WHEELS/requirements.txt"

if [ -n "${CLIP_PACK:-}" ]; then
  python lab/gpu/clip_pack.py pack "${CLIP_PACK%.pack.npz}" "$CLIP_PACK"
  CLIPS=$CLIP_PACK
elif ! ls "$SHARED"/mocap/deepmimic/motions/*.txt > /dev/null 2>&1; then
  echo "no DeepMimic motions in $SHARED/mocap/deepmimic/motions" >&2
  exit 1
else
  nice -n 19 fbcpr motions import "$SHARED"/mocap/deepmimic/motions/*.txt --out "$CLIPS" > /dev/null
  if [ -n "${SYNTHETIC:-}" ] && ! ls "$CLIPS"/synthetic_*.npz > /dev/null 2>&1; then  # the recipe's synthetic clips
    fbcpr motions synthetic --out "$CLIPS" > /dev/null
  fi
  echo "clips: $(ls "$CLIPS"/*.npz | wc -l) in $CLIPS"
fi

# What the GPU run copies: tracked files, untracked files git does not ignore, and the carried paths.
bytes() { du -cb "$@" 2>/dev/null | tail -n 1 | cut -f 1; }
tree=$( { git ls-files -z; git ls-files -z --others --exclude-standard; } | xargs -0 du -cb 2>/dev/null \
        | awk '$2 == "total" { s += $1 } END { print s + 0 }')
wheels=$(bytes "$WHEELS")
clips=$(bytes "$CLIPS")
total=$((tree + wheels + clips))
mib() { awk -v b="$1" 'BEGIN { printf "%.1f MiB", b / 1048576 }'; }
echo "tree $(mib "$tree") + $WHEELS $(mib "$wheels") + $CLIPS $(mib "$clips") = $(mib "$total") (limit $MAX_MIB MiB)"
if [ "$total" -gt $((MAX_MIB * 1048576)) ]; then
  echo "carry too large" >&2
  exit 1
fi
echo "carry: [\"$WHEELS\", \"$CLIPS\"]"
