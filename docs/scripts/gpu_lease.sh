#!/usr/bin/env bash
# The real-GPU figures of docs/notes/benchmarks.md in one call on a lent GPU machine, which
# runs one command of at most 600 s on a copy of the working tree, with at most 64 MiB of
# ignored files carried beside it and nothing to download:
#
#   bash docs/scripts/gpu_lease.sh pack           # here: release binaries (stripped) and
#                                                 # bonsai's data into out/lease (< 64 MiB)
#   bash docs/scripts/gpu_lease.sh run [PARTS]    # there, carrying out/lease; writes under
#                                                 # $OUT (default out/lease-results)
#
# PARTS (default: field step bonsai; then `run paper` in a second call), each stopped at its
# own time limit in seconds (`LEASE_<PART>_SECONDS`, defaults 45, 60 (twice), 30 (twice,
# `LEASE_RESOLVED_SECONDS`) and 10 (`LEASE_DISPATCH_SECONDS`), 320 and 540: one call stays
# under 560 s):
#   field   field.txt  the radiance field's step on the GPU (forward+backward samples/s at
#                      1,024 and 4,096 rays) and its renders (rays/s), CPU beside it
#   step    step.txt   whole splatting steps, GPU only: 200k and 1M Gaussians at 800×533,
#                      and the host's time per step outside its waits (the GPU's idle time);
#                      step_synthetic.txt the same with Staged's and Dual's batch of 20
#                      synthetic views at 1/8 the size; step_resolved.txt and
#                      step_synthetic_resolved.txt the same at 200k with each step resolved
#                      before the next is recorded (`--resolved`: no overlap of host and
#                      device, for the comparison); step_dispatch.txt what one small
#                      kernel launch costs the host to record, three ways
#   bonsai  bonsai/    the bonsai baseline on the GPU at 800×533 for 30,000 steps without a
#                      Gaussian cap (log.txt: the node's evaluations and refinements with
#                      their times and counts; summary.json when it finishes in time)
#   paper   paper/     paper_bonsai.ron with fragments/gpu.ron until the time is up
#                      (status.txt: each finished node's seconds; summary.json if it ends)
# gpu.csv samples nvidia-smi every 200 ms (utilisation %, memory MiB) throughout, when the
# machine has it; machine.txt names the adapter, the driver and the commit.
#
# A machine without a GPU runs it too (on lavapipe, slowly): `LEASE_SMOKE=1` shrinks every
# part to a check of the script itself (the demo pipeline, a few steps).
set -uo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
lease="$root/out/lease"

pack() {
  set -e
  cargo build --release -p augsplat --bin augsplat
  cargo build --release -p augsplat-field --example bench
  cargo build --release -p augsplat-splat --example gpu_train_step
  cargo build --release -p augsplat-render --example gpu_dispatch_cost
  rm -rf "$lease"
  mkdir -p "$lease/bin" "$lease/shared/data/bonsai"
  for b in augsplat examples/bench examples/gpu_train_step examples/gpu_dispatch_cost; do
    strip -o "$lease/bin/$(basename "$b")" "$root/target/release/$b"
  done
  local data="$root/../shared/data"
  # The binary models only (the pipelines read `colmapNN/sparse/0`) and the photos.
  for m in colmap30 colmap98; do
    mkdir -p "$lease/shared/data/bonsai/$m"
    cp -r "$data/bonsai/$m/sparse" "$lease/shared/data/bonsai/$m/"
  done
  cp -r "$data/bonsai/images" "$lease/shared/data/bonsai/"
  mkdir -p "$lease/shared/data/lpips"
  cp "$data/lpips/lpips_alex_v0.1.safetensors" "$lease/shared/data/lpips/"
  git -C "$root" rev-parse HEAD >"$lease/commit"
  du -sh "$lease"
  local mib=$(($(du -sm "$lease" | cut -f1)))
  [ "$mib" -lt 64 ] || { echo "out/lease is $mib MiB: over the 64 MiB carry limit" >&2; exit 1; }
}

# Runs a part's command under its time limit, its output (and how it ended) into FILE.
timed() {
  local limit=$1 file=$2
  shift 2
  local start=$SECONDS
  timeout --signal=INT --kill-after=10 "$limit" "$@" >"$file" 2>&1
  local rc=$?
  echo "# exit $rc after $((SECONDS - start)) s (limit $limit s)" >>"$file"
}

run() {
  local out="${OUT:-$root/out/lease-results}"
  mkdir -p "$out"
  [ -x "$lease/bin/augsplat" ] || { echo "no $lease/bin: pack first and carry out/lease" >&2; exit 1; }
  local bin="$lease/bin"
  local parts=("$@")
  [ ${#parts[@]} -gt 0 ] || parts=(field step bonsai)
  # The pipelines read ../../shared/data beside pipelines/: a copy of pipelines/ in a work
  # folder whose shared/ is the carried data.
  local work="$out/work"
  mkdir -p "$work/repo"
  rm -rf "$work/repo/pipelines"
  cp -r "$root/pipelines" "$work/repo/pipelines"
  ln -sfn "$lease/shared" "$work/shared"
  {
    echo "commit $(cat "$lease/commit" 2>/dev/null)"
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv 2>/dev/null
    nproc
  } >"$out/machine.txt"
  local smi_pid=""
  if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv,noheader,nounits \
      -lms 200 >"$out/gpu.csv" 2>/dev/null &
    smi_pid=$!
  fi
  local smoke="${LEASE_SMOKE:-}"
  for part in "${parts[@]}"; do
    echo "== $part ($(date -u +%T))" >>"$out/parts.txt"
    case "$part" in
      field)
        timed "${LEASE_FIELD_SECONDS:-45}" "$out/field.txt" \
          "$bin/bench" "$(nproc)" gpu "$([ -n "$smoke" ] && echo 2 || echo 20)"
        ;;
      step)
        if [ -n "$smoke" ]; then
          timed "${LEASE_STEP_SECONDS:-60}" "$out/step.txt" \
            "$bin/gpu_train_step" 2000 64x48 2 --no-cpu
          timed "${LEASE_STEP_SECONDS:-60}" "$out/step_synthetic.txt" \
            "$bin/gpu_train_step" 2000 64x48 2 --no-cpu --synthetic 3
          timed "${LEASE_DISPATCH_SECONDS:-10}" "$out/step_dispatch.txt" \
            "$bin/gpu_dispatch_cost" 100 2
        else
          timed "${LEASE_STEP_SECONDS:-60}" "$out/step.txt" \
            "$bin/gpu_train_step" 200000,1000000 800x533 20 --no-cpu
          timed "${LEASE_STEP_SECONDS:-60}" "$out/step_synthetic.txt" \
            "$bin/gpu_train_step" 200000 800x533 20 --no-cpu --synthetic 20
          timed "${LEASE_RESOLVED_SECONDS:-30}" "$out/step_resolved.txt" \
            "$bin/gpu_train_step" 200000 800x533 20 --no-cpu --resolved
          timed "${LEASE_RESOLVED_SECONDS:-30}" "$out/step_synthetic_resolved.txt" \
            "$bin/gpu_train_step" 200000 800x533 20 --no-cpu --synthetic 20 --resolved
          timed "${LEASE_DISPATCH_SECONDS:-10}" "$out/step_dispatch.txt" \
            "$bin/gpu_dispatch_cost" 2000 6
        fi
        ;;
      bonsai)
        mkdir -p "$out/bonsai"
        local sets=(--set baseline.backend=Gpu --set params.max_gaussians=0
          --set params.patience=None)
        if [ -n "$smoke" ]; then
          sets+=(--set params.gs_steps=30 --set params.eval_every=10)
          local pipeline="$work/repo/pipelines/demo.ron"
        else
          sets+=(--set scene.downscale=1 --set params.gs_steps=30000 --set params.eval_every=3000)
          local pipeline="$work/repo/pipelines/bonsai.ron"
        fi
        timed "${LEASE_BONSAI_SECONDS:-320}" "$out/bonsai/log.txt" \
          "$bin/augsplat" run "$pipeline" "${sets[@]}" --target eval_baseline --log -q \
          --cache "$work/store-bonsai" --summary-json "$out/bonsai/summary.json"
        ;;
      paper)
        mkdir -p "$out/paper"
        printf '(extends: ["%s", "fragments/gpu.ron"])\n' \
          "$([ -n "$smoke" ] && echo demo.ron || echo paper_bonsai.ron)" \
          >"$work/repo/pipelines/lease_paper.ron"
        timed "${LEASE_PAPER_SECONDS:-540}" "$out/paper/log.txt" \
          "$bin/augsplat" run "$work/repo/pipelines/lease_paper.ron" --log -q \
          --cache "$work/store-paper" --summary-json "$out/paper/summary.json"
        # What finished, with its seconds, even when the time ran out first.
        "$bin/augsplat" status --cache "$work/store-paper" >"$out/paper/status.txt" 2>&1
        ;;
      *) echo "unknown part $part (field, step, bonsai, paper)" >&2 ;;
    esac
  done
  [ -z "$smi_pid" ] || kill "$smi_pid" 2>/dev/null
  # The stores stay out of what comes back (their outputs are large); the logs say enough.
  rm -rf "$work"
  ls -la "$out"
}

case "${1:-}" in
  pack) pack ;;
  run) shift; run "$@" ;;
  *) sed -n 2,29p "$0"; exit 2 ;;
esac
