#!/usr/bin/env bash
# CI: training must not depend on the CPU's cache. `gemm` sizes its blocks
# along a product's inner dimension from the L1 cache it reads in
# /sys/devices/system/cpu/cpuN/cache, and the block length decides the order
# of the sum; `motion_vrnn::blocks::kernels::mm` cuts that dimension itself
# (docs/training.md, "Speed"). This trains the default model (conditioned on
# the category, the pace and the control) and the motion classifier for 2
# epochs each, twice: once as
# the machine is and once with the L1 shown to `gemm` as another CPU's (48 KiB
# 12-way, or 32 KiB 8-way where the real one is 48 KiB; a copy of the cache
# folders, bind-mounted inside a private mount namespace), and wants identical
# weights.
#
# Needs `unshare -m` (root, or a user namespace); without it, it says
# "skipped" and why. Usage: .ci/cache-check.sh [XTASK] (default
# target/release/xtask, built by `cargo test --workspace --release`).
set -euo pipefail
cd "$(dirname "$0")/.."

xtask="${1:-${CARGO_TARGET_DIR:-target}/release/xtask}"
[ -x "$xtask" ] || { echo "cache-check: no $xtask: build it first (cargo build --release -p xtask)" >&2; exit 1; }
shared="${CMU_SHARED_DIR:-../shared/cmu}"
[ -f "$shared/cmu-asfamc-sample.zip" ] || { echo "cache-check: missing $shared/cmu-asfamc-sample.zip" >&2; exit 1; }
if ! unshare -m true 2>/dev/null; then
  echo "skipped: cannot make a private mount namespace here (unshare -m), so the cache cannot be faked"
  exit 0
fi

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
# The L1 as another CPU has it (not as this one: faking the real size would
# test nothing); every other cache level as it is.
fake_size=48K fake_ways=12
for index in /sys/devices/system/cpu/cpu0/cache/index*; do
  if [ "$(cat "$index/level" 2>/dev/null)" = 1 ] && [ "$(cat "$index/type" 2>/dev/null)" = Data ] \
    && [ "$(cat "$index/size" 2>/dev/null)" = 48K ]; then
    fake_size=32K fake_ways=8
  fi
done
for cpu in /sys/devices/system/cpu/cpu[0-9]*; do
  [ -d "$cpu/cache" ] || continue
  fake="$work/fake/$(basename "$cpu")"
  for index in "$cpu"/cache/index*; do
    mkdir -p "$fake/$(basename "$index")"
    for f in "$index"/*; do
      [ -f "$f" ] && cat "$f" >"$fake/$(basename "$index")/$(basename "$f")" 2>/dev/null || true
    done
  done
  for index in "$fake"/index*; do
    if [ "$(cat "$index/level")" = 1 ] && [ "$(cat "$index/type")" = Data ]; then
      echo "$fake_size" >"$index/size"
      echo "$fake_ways" >"$index/ways_of_associativity"
      echo 64 >"$index/number_of_sets"
    fi
  done
done
[ -d "$work/fake" ] || { echo "skipped: no cache folders in /sys/devices/system/cpu"; exit 0; }

log="$work/log"
quiet() { "$@" >"$log" 2>&1 || { cat "$log" >&2; echo "cache-check: $* failed" >&2; exit 1; }; }
quiet "$xtask" dataset --source "$shared/cmu-asfamc-sample.zip" --out "$work/data"
train=(train --data "$work/data" --preset quick --epochs 2 --condition category+pace+control --seed 3)
quiet "$xtask" "${train[@]}" --out "$work/real"
quiet "$xtask" train-classifier --data "$work/data" --epochs 2 --out "$work/real-classifier"
# shellcheck disable=SC2016
unshare -m bash -c '
  set -e
  for fake in "$1"/fake/cpu*; do
    mount --bind "$fake" "/sys/devices/system/cpu/$(basename "$fake")/cache"
  done
  [ "$(cat /sys/devices/system/cpu/cpu0/cache/index0/size)" = "$3" ] || [ "$(cat /sys/devices/system/cpu/cpu0/cache/index1/size)" = "$3" ]
  work="$1"; xtask="$2"; shift 3
  "$xtask" "$@" --out "$work/faked"
  "$xtask" train-classifier --data "$work/data" --epochs 2 --out "$work/faked-classifier"
' cache-check "$work" "$xtask" "$fake_size" "${train[@]}" >"$log" 2>&1 \
  || { cat "$log" >&2; echo "cache-check: training with the faked cache failed" >&2; exit 1; }
for ck in last best; do
  cmp "$work/real/$ck/model.safetensors" "$work/faked/$ck/model.safetensors" \
    || { echo "cache-check: the $ck weights differ when gemm sees an L1 of $fake_size" >&2; exit 1; }
done
cmp "$work/real-classifier/classifier.safetensors" "$work/faked-classifier/classifier.safetensors" \
  || { echo "cache-check: the classifier's weights differ when gemm sees an L1 of $fake_size" >&2; exit 1; }
echo "the same weights (default model, classifier) with the L1 cache as it is and as $fake_size $fake_ways-way"
