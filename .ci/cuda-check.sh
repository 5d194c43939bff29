#!/usr/bin/env bash
# CI: compile the `cuda` feature (candle's CUDA backend) without a GPU.
#
# No GPU or NVIDIA driver is needed: `cargo check` runs candle-kernels' nvcc
# step and type-checks everything, but links nothing. The toolkit comes from
# NVIDIA's PyPI wheels, installed into a virtual environment under target/
# (gitignored, kept between runs). It is pinned: cudarc (Cargo.lock) reads the
# version from `nvcc --version` and refuses a CUDA newer than it knows (13.4).
# The check uses its own target directory so that the main build cache, built
# without the feature, is left alone. A second run reuses both (seconds).
#
# Knobs (environment): CUDA_VENV (default target/cuda-venv),
# CUDA_TARGET_DIR (default target/cuda), CUDA_COMPUTE_CAP (default 90:
# H100/H200; nvidia-smi would otherwise be asked, and there is none).
set -euo pipefail
cd "$(dirname "$0")/.."

die() { echo "cuda-check: $*" >&2; exit 1; }

toolkit='cuda-toolkit[nvcc,cudart,cublas,curand,nvrtc,cccl]==13.4.3'
cuda_release='13.4'
venv="${CUDA_VENV:-target/cuda-venv}"
target_dir="${CUDA_TARGET_DIR:-target/cuda}"
stamp="$venv/.cuda-toolkit"

# --- the toolkit (pip) -------------------------------------------------------
t0=$(date +%s)
if [ -x "$venv/bin/python" ] && [ "$(cat "$stamp" 2>/dev/null)" = "$toolkit" ]; then
  echo "reusing $venv ($toolkit)"
else
  command -v python3 >/dev/null 2>&1 || die "python3 not found: it is needed to install the CUDA toolkit from PyPI"
  rm -rf "$venv"
  mkdir -p "$(dirname "$venv")"
  python3 -m venv "$venv" || die "python3 -m venv $venv failed (on Debian/Ubuntu: apt-get install python3-venv)"
  echo "pip install $toolkit (about 1.2 GB installed)"
  "$venv/bin/python" -m pip install --disable-pip-version-check --quiet "$toolkit" \
    || die "pip install '$toolkit' failed (network? PyPI?)"
  echo "$toolkit" >"$stamp"
fi
site="$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
CUDA_HOME="$site/nvidia/cu13"
[ -x "$CUDA_HOME/bin/nvcc" ] || die "no nvcc at $CUDA_HOME/bin/nvcc: the wheels' layout changed? (remove $venv and retry)"
export CUDA_HOME
export PATH="$CUDA_HOME/bin:$PATH"
export CUDA_COMPUTE_CAP="${CUDA_COMPUTE_CAP:-90}"
# Only CUDA_HOME may point at a toolkit, else cudarc would also search others.
unset CUDA_PATH CUDA_ROOT CUDA_TOOLKIT_ROOT_DIR
nvcc_version="$(nvcc --version)" || die "$CUDA_HOME/bin/nvcc --version failed"
grep -q "release $cuda_release," <<<"$nvcc_version" \
  || die "nvcc is not CUDA $cuda_release (cudarc in Cargo.lock needs <= 13.4): $(tail -2 <<<"$nvcc_version" | head -1)"
pip_s=$(( $(date +%s) - t0 ))
echo "CUDA_HOME=$CUDA_HOME (nvcc $cuda_release), CUDA_COMPUTE_CAP=$CUDA_COMPUTE_CAP"
echo "toolkit step: ${pip_s}s"

# --- cargo check --features cuda ---------------------------------------------
# Every crate that defines `cuda`: motion-vrnn (candle-core/cuda, candle-nn/cuda)
# and xtask (forwards it); all their targets, tests included.
t0=$(date +%s)
CARGO_TARGET_DIR="$target_dir" cargo check --release -p motion-vrnn -p xtask --all-targets --features cuda \
  || die "cargo check --features cuda failed (see above)"
check_s=$(( $(date +%s) - t0 ))
echo "cargo check --features cuda: ${check_s}s (toolkit step ${pip_s}s)"
