#!/usr/bin/env bash
# The CUDA path on a GPU (not run by CI, which has none): every model trains a
# few epochs on the GPU and on the CPU, and their losses must agree to 1e-4
# relative; a checkpoint then generates on both. docs/training.md, "GPU".
#
#   .ci/cuda-gpu-check.sh build [DIR]   # any x86-64 Linux, no GPU needed
#   .ci/cuda-gpu-check.sh run [DIR]     # on the GPU machine, from the repo root
#
# `build` writes DIR/xtask.xz (default DIR: .devcarry, which you exclude in
# .git/info/exclude): xtask built with `--features cuda`, stripped. Its PTX
# must not be newer than the GPU machine's driver (nvidia-smi, "CUDA
# Version"), so the toolkit's release is a knob: CUDA_RELEASE (default 13.0,
# driver 580). Without a driver there is no libcuda.so to link against, so a
# stub of the driver functions cudarc declares stands in for it; the real
# libcuda.so.1 is loaded at run time.
#
# `run` needs the binary in DIR and the dataset data/datasets/shared (`cargo
# xtask dataset` on the shared samples); it finds the toolkit's libraries
# (cuBLAS, cuRAND, the CUDA runtime) with `find` and prints one verdict line
# per model. Its logs and runs go to ${OUT:-/tmp}/cuda-gpu-check.tgz.
# CHECK_ROWS="minute paper-preset" runs only the rows named (default: all of them).
set -euo pipefail
cd "$(dirname "$0")/.."
die() { echo "cuda-gpu-check: $*" >&2; exit 1; }
mode="${1:-}"
dir="${2:-.devcarry}"

build() {
  local rel="${CUDA_RELEASE:-13.0}" venv target pins lock reg stub
  case "$rel" in
    13.0) pins='cuda-toolkit[nvcc,cudart,cublas,curand,nvrtc,cccl]==13.0.2 nvidia-nvvm==13.0.88 nvidia-cuda-crt==13.0.88' ;;
    13.4) pins='cuda-toolkit[nvcc,cudart,cublas,curand,nvrtc,cccl]==13.4.3' ;;
    *) die "CUDA_RELEASE=$rel: 13.0 or 13.4" ;;
  esac
  venv="target/cuda$rel-venv"
  target="target/cuda$rel-build"
  if [ "$(cat "$venv/.pins" 2>/dev/null)" != "$pins" ]; then
    rm -rf "$venv"
    python3 -m venv "$venv" || die "python3 -m venv failed"
    # shellcheck disable=SC2086
    "$venv/bin/python" -m pip install --disable-pip-version-check -q $pins || die "pip install $pins failed"
    echo "$pins" >"$venv/.pins"
  fi
  CUDA_HOME="$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/nvidia/cu13"
  export CUDA_HOME PATH="$CUDA_HOME/bin:$PATH" CUDA_COMPUTE_CAP="${CUDA_COMPUTE_CAP:-90}"
  unset CUDA_PATH CUDA_ROOT CUDA_TOOLKIT_ROOT_DIR
  nvcc --version | grep -q "release $rel," || die "nvcc is not CUDA $rel"
  # The linker wants unversioned names; cudarc's build script also searches
  # $CUDA_HOME/lib/stubs, where the driver stub goes.
  lock=$(grep -A1 '^name = "cudarc"' Cargo.lock | sed -n 's/^version = "\(.*\)"/\1/p')
  reg="${CARGO_HOME:-$HOME/.cargo}/registry/src"
  local sys
  sys=$(ls "$reg"/*/"cudarc-$lock"/src/driver/sys/mod.rs 2>/dev/null | head -1)
  [ -n "$sys" ] || die "cudarc $lock's sources not found under $reg (run cargo fetch)"
  stub="$CUDA_HOME/lib/stubs"
  mkdir -p "$stub"
  grep -ohP '^\s+fn \Kcu\w+(?=\()' "$sys" | sort -u | awk '{print "void " $1 "(void){}"}' >"$stub/stub.c"
  cc -shared -fPIC -Wl,-soname,libcuda.so.1 -o "$stub/libcuda.so" "$stub/stub.c"
  for l in cublas cublasLt cudart nvrtc; do ln -sfn "lib$l.so.13" "$CUDA_HOME/lib/lib$l.so"; done
  ln -sfn libcurand.so.10 "$CUDA_HOME/lib/libcurand.so"
  CARGO_TARGET_DIR="$target" cargo build --release -p xtask --features cuda \
    || die "cargo build --features cuda failed"
  mkdir -p "$dir"
  strip -o "$dir/xtask" "$target/release/xtask"
  xz -T0 -6 -f "$dir/xtask"
  ls -l "$dir/xtask.xz"
}

run() {
  local data=data/datasets/shared work=/tmp/cuda-gpu-check x=/tmp/cuda-gpu-check/xtask
  [ -f "$dir/xtask.xz" ] || die "no $dir/xtask.xz: run '$0 build' first"
  [ -d "$data" ] || die "no dataset at $data (cargo xtask dataset --out $data on the shared samples)"
  rm -rf "$work" && mkdir -p "$work"
  xz -dc "$dir/xtask.xz" >"$x" && chmod +x "$x"
  local lp
  lp=$(find /opt /usr /usr/local -xdev \( -name 'libcublas.so.13' -o -name 'libcublasLt.so.13' \
    -o -name 'libcurand.so.10' -o -name 'libcudart.so.13' -o -name 'libnvrtc.so.13' \
    -o -name 'libcuda.so.1' \) -printf '%h\n' 2>/dev/null | sort -u | paste -sd: || true)
  export LD_LIBRARY_PATH="$lp:/usr/local/nvidia/lib64${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
  nvidia-smi --query-gpu=name,driver_version --format=csv,noheader || echo "nvidia-smi failed"
  ! ldd "$x" | grep 'not found' || die "libraries missing (above)"
  train() { # NAME DEVICE(gpu|cpu) ARGS…
    local n=$1 d=$2 s rc hide=()
    shift 2
    s=$(date +%s)
    # On `cpu` no GPU is visible, so the same binary trains on the CPU.
    [ "$d" = cpu ] && hide=(env CUDA_VISIBLE_DEVICES=)
    "${hide[@]}" timeout 300 "$x" train --data "$data" --seed 0 --epochs 5 \
      --out "$work/$d/$n" "$@" >"$work/$d-$n.log" 2>&1 && rc=0 || rc=$?
    echo "$n on $d: rc $rc, $(($(date +%s) - s)) s, ran $(grep -o 'on CUDA GPU [0-9]*\|on the CPU' "$work/$d-$n.log" | head -1)"
    [ "$rc" = 0 ] || grep -A3 '^Error' "$work/$d-$n.log" | head -4
    if [ "$d" = gpu ] && ! grep -q 'on CUDA GPU' "$work/$d-$n.log"; then
      echo "$n: not on the GPU" >>"$work/failures"
    fi
  }
  local m all="paper smooth skeletal feet fed motion minute paper-preset"
  local rows="${CHECK_ROWS:-$all}"
  for m in $rows; do
    case " $all " in *" $m "*) ;; *) die "CHECK_ROWS: no row $m (rows: $all)" ;; esac
  done
  row() { case " $rows " in *" $1 "*) ;; *) return ;; esac; train "$@"; }
  # Every model with the `standard` preset, then the default (`minute`).
  for m in paper smooth skeletal feet fed motion; do
    row "$m" gpu --model "$m" --preset standard
    row "$m" cpu --model "$m" --preset standard
  done
  # The minute preset: feed rounds at the temperature and the pace as a condition.
  row minute gpu --preset minute
  row minute cpu --preset minute
  row paper-preset gpu --model paper --preset paper
  row paper-preset cpu --model paper --preset paper
  # Sampling the default's run exercises the pace on the sampling path too.
  if [ -d "$work/gpu/minute" ]; then
    "$x" sample --run "$work/gpu/minute" --n 8 --frames 256 --out "$work/sample-gpu" >"$work/sample-gpu.log" 2>&1 || echo "sample on the GPU failed"
    CUDA_VISIBLE_DEVICES= "$x" sample --run "$work/gpu/minute" --n 8 --frames 256 --out "$work/sample-cpu" >"$work/sample-cpu.log" 2>&1 || echo "sample on the CPU failed"
  fi
  local rc=0
  python3 - "$work" $rows <<'EOF' || rc=$?
import json, os, sys
w = sys.argv[1]
keys = ["train_recon", "train_kl", "val_recon", "val_kl"]
bad = 0
if os.path.exists(os.path.join(w, "failures")):
    print(open(os.path.join(w, "failures")).read(), end=""); bad += 1
for n in sys.argv[2:]:
    p = [os.path.join(w, d, n, "metrics.jsonl") for d in ("gpu", "cpu")]
    if not all(map(os.path.exists, p)):
        print(f"{n:13s} MISSING"); bad += 1; continue
    g, c = ([json.loads(l) for l in open(f)] for f in p)
    worst = max(abs(a[k] - b[k]) / abs(b[k]) for a, b in zip(g, c) for k in keys)
    # The judge's scores, where it judged.
    judged = [(a["generated"]["score"], b["generated"]["score"]) for a, b in zip(g, c) if a.get("generated") and b.get("generated")]
    judge = max((abs(x - y) / abs(y) for x, y in judged), default=0.0)
    ok = len(g) == len(c) and worst <= 1e-4 and judge <= 1e-4
    bad += not ok
    print(f"{n:13s} {len(g)} epochs, losses GPU vs CPU: worst relative difference {worst:.1e}, judge {judge:.1e} {'ok' if ok else 'FAIL'}")
try:
    if "minute" not in sys.argv[2:]:
        raise SystemExit(1 if bad else 0)
    import numpy as np, pyarrow.parquet as pq
    for f in ["samples", "reconstructions"]:
        a, b = (pq.read_table(os.path.join(w, d, f + ".parquet")) for d in ("sample-gpu", "sample-cpu"))
        diff = max(float(np.max(np.abs(a[k].to_numpy() - b[k].to_numpy()))) for k in "xyz")
        print(f"{f}: {a.num_rows} joint positions, GPU vs CPU: max difference {diff:.1e} (CMU units)")
except Exception as e:
    print("sample comparison failed:", e); bad += 1
sys.exit(1 if bad else 0)
EOF
  rm -rf "$work"/sample-*/anim "$work/xtask"
  tar czf "${OUT:-/tmp}/cuda-gpu-check.tgz" -C /tmp cuda-gpu-check
  if [ "$rc" = 0 ]; then echo "cuda-gpu-check: passed"; else echo "cuda-gpu-check: FAILED (see above)"; fi
  return $rc
}

case "$mode" in
  build) build ;;
  run) run ;;
  *) die "usage: $0 build|run [DIR]" ;;
esac
