#!/usr/bin/env bash
# The trace and foveation benchmarks at the thesis's resolution (2 x 1280x1024) on a CUDA machine,
# in at most 11 minutes (each of the three stops at 220 s): prints Mrays/s of the Warp and JAX
# backends on the atrium's rays (benchmarks/trace_warp.py), of the JAX backend against its peers
# (benchmarks/trace_throughput.py), and frames per second (benchmarks/foveation.py --full).
#
#   bash benchmarks/gpu.sh --fetch-wheels     # on a machine with PyPI: fill benchmarks/wheels/
#   bash benchmarks/gpu.sh                    # on the GPU machine (no network), from the repo root
#   bash benchmarks/gpu.sh --tiny --no-install   # a quick check of the script on any machine
#   bash benchmarks/gpu.sh --tiny --no-install --warp-only   # just the Warp/JAX rows (Warp on CPU)
#
# Warp (warp-lang, the [gpu] extra) is a ~150 MB binary wheel: --fetch-wheels puts it in
# benchmarks/wheels/warp/ (apart from the small wheels, so those can be carried alone); it is
# installed from there when the machine has no warp, and without either the Warp rows say so.
#
# The GPU machines this project may be lent hold jax with its CUDA plugin, equinox, optimistix and
# lineax, and cannot download anything. The project's other pure-Python dependencies travel as
# wheels in benchmarks/wheels/ (about 1 MiB; not committed: make it with --fetch-wheels and carry
# it), installed with --no-deps, then the project itself with --no-deps. The binary ones
# (matplotlib, pillow) are not carried: neither benchmark imports them.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python}
WHEELS=benchmarks/wheels
TINY=0
INSTALL=1
WARP_ONLY=0
# Pure-Python runtime dependencies of fovjax (pyproject.toml) beyond jax/equinox/optimistix/lineax.
PURE_DEPS=(trimesh emcee pyserial jaxtyping wadler_lindig imageio tqdm)

while [[ $# -gt 0 ]]; do
    case "$1" in
        --fetch-wheels)
            mkdir -p "$WHEELS"
            "$PY" -m pip download --no-deps --only-binary=:all: -d "$WHEELS" "${PURE_DEPS[@]}"
            "$PY" -m pip download --no-deps --only-binary=:all: -d "$WHEELS/warp" "warp-lang>=1.19"
            ls -l "$WHEELS" "$WHEELS/warp"
            exit 0
            ;;
        --tiny) TINY=1 ;;
        --no-install) INSTALL=0 ;;
        --warp-only) WARP_ONLY=1 ;;
        --wheels) WHEELS=$2; shift ;;
        *) echo "gpu.sh: unknown option $1 (expected --fetch-wheels, --tiny, --no-install, --warp-only, --wheels DIR)" >&2; exit 2 ;;
    esac
    shift
done

date -u +"%Y-%m-%d %H:%M UTC"
if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
else
    echo "nvidia-smi not found"
fi

if [[ $INSTALL == 1 ]]; then
    shopt -s nullglob
    wheels=("$WHEELS"/*.whl)
    if [[ ${#wheels[@]} -eq 0 ]]; then
        echo "gpu.sh: no wheels in $WHEELS (make them with: bash benchmarks/gpu.sh --fetch-wheels)" >&2
    else
        "$PY" -m pip install -q --no-index --no-deps "${wheels[@]}"
    fi
    warp_wheels=("$WHEELS"/warp/*.whl)
    if ! "$PY" -c "import warp" 2>/dev/null && [[ ${#warp_wheels[@]} -gt 0 ]]; then
        "$PY" -m pip install -q --no-index --no-deps "${warp_wheels[@]}"
    fi
    # No build isolation: pip would try to download setuptools. The PYTHONPATH below covers a
    # machine without setuptools too.
    "$PY" -m pip install -q --no-deps --no-build-isolation -e . ||
        echo "gpu.sh: pip install -e . failed; running from the source tree (PYTHONPATH)" >&2
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"

"$PY" - <<'EOF'
import jax
d = jax.devices()[0]
print(f"jax {jax.__version__}: {jax.device_count()} {d.platform} device(s), {d.device_kind}")
if d.platform != "gpu":
    print("gpu.sh: no GPU visible to JAX; the figures below are this machine's CPU")
EOF

if [[ $TINY == 1 ]]; then
    warp_args=(--width 64 --height 48 --random 4096 --repeats 1)
    trace_args=(--width 64 --height 48 --random 4096 --repeats 1 --rows primary random --peers)
    fov_args=(--spp 1 --repeats 1)
    limit=600
else
    # One ray per pixel of both eyes (2 x 1280 x 1024 = 2560 x 1024), 2M random rays; no CPU peers.
    warp_args=(--width 2560 --height 1024 --random 2097152 --repeats 3 --warp-bvh sah lbvh)
    trace_args=(--width 2560 --height 1024 --random 2097152 --repeats 3 --peers)
    fov_args=(--full --spp 1 4 --repeats 3)
    limit=220
fi

echo
echo "== Warp and JAX backends, the atrium's primary, random and shadow rays (Mrays/s) =="
if "$PY" -c "import warp" 2>/dev/null; then
    timeout "$limit" "$PY" benchmarks/trace_warp.py "${warp_args[@]}" ||
        echo "gpu.sh: Warp benchmark stopped (exit $?)"
else
    echo "gpu.sh: warp-lang is not installed (pip install 'fovjax[gpu]', or --fetch-wheels): no Warp rows"
fi
[[ $WARP_ONLY == 1 ]] && exit 0

echo
echo "== ray queries (Mrays/s) =="
timeout "$limit" "$PY" benchmarks/trace_throughput.py "${trace_args[@]}" ||
    echo "gpu.sh: trace benchmark stopped (exit $?)"
echo
echo "== foveated vs full stereo frames (frames per second) =="
timeout "$limit" "$PY" benchmarks/foveation.py "${fov_args[@]}" ||
    echo "gpu.sh: foveation benchmark stopped (exit $?)"
