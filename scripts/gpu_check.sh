#!/usr/bin/env bash
# The GPU check in one call, on the device machine (no network) or any CUDA machine (docs/gpu.md):
#
#   bash scripts/gpu_check.sh [--dry-run] [--budget SECONDS] [--out DIR] [--kit DIR] [--python PY] [--skip-train]
#
# Installs the offline kit (`make gpu-kit`: .whl/) into a fresh temporary folder with
# `pip install --no-index --no-deps --target` (the machine's torch is never touched; the script
# checks it), then runs `ftgspp check-gpu` within the budget (default 480 s, counted from this
# script's start): gsplat compiled once, parity on the real kernels, quick runs gsplat vs cpu,
# benches at 5k and 500k Gaussians, the paper profile for the time left. Everything goes to
# $OUT (default outputs/gpu-check): log.txt, summary.txt, results.json, runs.tar.gz.
# --dry-run needs no GPU: it goes up to the first CUDA call, answered by the torch stand-ins of
# tests/render/gsplat_standins.py (default Python there: .venv/bin/python when it exists).
set -uo pipefail
T0=$(date +%s)
cd "$(dirname "$0")/.."

DRY=0 BUDGET=480 KIT=.whl OUTDIR="${OUT:-outputs/gpu-check}" PY="" EXTRA=()
while [ $# -gt 0 ]; do
  case "$1" in
    --dry-run) DRY=1 ;;
    --budget) BUDGET=$2; shift ;;
    --out) OUTDIR=$2; shift ;;
    --kit) KIT=$2; shift ;;
    --python) PY=$2; shift ;;
    --skip-train) EXTRA+=(--skip-train) ;;
    -h|--help) sed -n '2,13p' "$0"; exit 0 ;;
    *) echo "gpu_check.sh: unknown argument '$1' (--help lists them)" >&2; exit 2 ;;
  esac
  shift
done
if [ -z "$PY" ]; then
  if [ "$DRY" = 1 ] && [ -x .venv/bin/python ]; then PY=.venv/bin/python; else PY=python3; fi
fi
mkdir -p "$OUTDIR"
OUTDIR=$(cd "$OUTDIR" && pwd)

main() {
  if [ ! -f "$KIT/kit.json" ]; then
    echo "gpu_check.sh: no kit in $KIT/ (run 'make gpu-kit' where PyPI is reachable; the device tool carries it: docs/gpu.md)"
    return 2
  fi
  KIT=$(cd "$KIT" && pwd)
  local kit_py here_py torch_before torch_after site wheels
  kit_py=$("$PY" -c 'import json, sys; print(json.load(open(sys.argv[1]))["python"])' "$KIT/kit.json") || return 2
  here_py=$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
  torch_before=$("$PY" -c 'import torch; print(torch.__version__, torch.__file__)') || { echo "gpu_check.sh: $PY has no torch"; return 2; }
  site=$(mktemp -d "${TMPDIR:-/tmp}/ftgspp-kit.XXXXXX")
  trap 'rm -rf "$site"' EXIT
  if [ "$kit_py" = "$here_py" ]; then
    wheels=("$KIT"/*.whl)
  else  # a dry run under another Python: its compiled wheels cannot load here; pip's resolution checks them
    wheels=("$KIT"/*-none-any.whl)
    echo "note: the kit is for CPython $kit_py, this is $here_py: installing its pure-Python wheels only"
  fi
  echo "installing the kit offline: ${#wheels[@]} wheels -> $site"
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --disable-pip-version-check \
    --target "$site" "${wheels[@]}" || { echo "gpu_check.sh: the kit did not install"; return 3; }
  export PYTHONPATH="$site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
  torch_after=$("$PY" -c 'import torch; print(torch.__version__, torch.__file__)')
  if [ "$torch_before" != "$torch_after" ] || [ -e "$site/torch" ]; then
    echo "gpu_check.sh: the kit would replace the machine's torch ($torch_before -> $torch_after)"
    return 3
  fi
  echo "torch untouched: $torch_after"
  export FTGSPP_LPIPS_WEIGHTS="$KIT/lpips" PYTHONUNBUFFERED=1 MPLBACKEND=Agg
  # gsplat compiles once into this folder; every later process, and a re-run on the same machine, loads it
  export TORCH_EXTENSIONS_DIR="${TORCH_EXTENSIONS_DIR:-${TMPDIR:-/tmp}/ftgspp-torch-extensions}"
  local mode=()
  [ "$DRY" = 1 ] && mode=(--dry-run)
  "$PY" -m harness.cli.ftgspp_cmd check-gpu --out "$OUTDIR" --budget "$BUDGET" --started "$T0" \
    --kit "$KIT" --kit-site "$site" "${mode[@]}" "${EXTRA[@]}"
}

main 2>&1 | tee "$OUTDIR/log.txt"
exit "${PIPESTATUS[0]}"
