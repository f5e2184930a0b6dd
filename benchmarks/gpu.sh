#!/usr/bin/env bash
# The GPU checks at the thesis's resolution (2 x 1280x1024) on a CUDA machine, sized for a 15-minute
# lease: at most --total seconds (540 by default, so under 10 minutes with the install), each step
# stopped at its own limit or at what is left of the total, whichever comes first:
#   1. the Warp tests on the GPU (tests/test_trace_warp.py: Warp's queries against brute force and
#      the JAX traversal; tests/test_render_warp.py: the Warp integrator against the JAX one),
#   2. the frame with the Warp integrator (benchmarks/warp_frame.py): full SPP 1 and 4, foveated
#      5°/10° SPP 1 and 4 at an off-centre gaze, the JAX integrator's full SPP 1 beside them, and a
#      jax.profiler summary of one full and one foveated frame (kernels, copies, host syncs,
#      Python callbacks per frame), written as a record,
#   3. Mrays/s of the Warp and JAX backends on the atrium's rays (benchmarks/trace_warp.py),
#   and with --all, the foveated against the full frame (benchmarks/foveation.py --full --speedup)
#   and the JAX backend against its CPU peers (benchmarks/trace_throughput.py).
# Records of the benchmarks land in benchmarks/results/ (and in --out DIR, when given).
#
#   bash benchmarks/gpu.sh --fetch-wheels     # on a machine with PyPI: fill benchmarks/wheels/
#   bash benchmarks/gpu.sh --warp-cache       # on any machine with Warp: compile Warp's kernels for
#                                             # sm_90 (H100, H200) into benchmarks/warp_cache/
#   bash benchmarks/gpu.sh                    # on the GPU machine (no network), from the repo root
#   bash benchmarks/gpu.sh --dry-run          # a quick check of the script on any machine (no records)
#   bash benchmarks/gpu.sh --tiny --no-install --warp-only   # just the Warp/JAX rows (Warp on CPU; no records)
#
# Warp compiles each of its modules for the GPU on first use (NVRTC, seconds each, on the lease's
# time); with benchmarks/warp_cache/ present (made by --warp-cache here, carried there) Warp loads
# them from it instead (WARP_CACHE_PATH), and the script says which it compiled anew anyway.
#
# Warp (warp-lang, the [gpu] extra) is a ~150 MB binary wheel: --fetch-wheels puts it in
# benchmarks/wheels/warp/ (apart from the small wheels, so those can be carried alone); it is
# installed from there when the machine has no warp, and without either the Warp rows say so.
# Where a transfer limit is below the wheel's size, --warp-parts DIR instead: a folder made by
# --split-warp DIR here (Warp's Python files and its CUDA library, xz-compressed in parts of at
# most 45 MiB that can travel one at a time; its CPU compiler, warp-clang, is left out: Warp then
# has no CPU device), put back together there into a folder on PYTHONPATH.
#
# The GPU machines this project may be lent hold jax with its CUDA plugin, equinox, optimistix and
# lineax, and cannot download anything. The project's other pure-Python dependencies travel as
# wheels in benchmarks/wheels/ (about 1 MiB; not committed: make it with --fetch-wheels and carry
# it), installed with --no-deps, then the project itself with --no-deps. The binary ones
# (matplotlib, pillow) are not carried: no step imports them.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python}
WHEELS=benchmarks/wheels
TINY=0
INSTALL=1
WARP_ONLY=0
ALL=0
LIMIT=150
TOTAL=540
WARP_CACHE=benchmarks/warp_cache
MAKE_CACHE=0
ARCH=90
START=$SECONDS
OUTDIR=""
WARP_PARTS=""
# Pure-Python dependencies of fovjax (pyproject.toml) beyond jax/equinox/optimistix/lineax, and
# beartype, which the tests check shapes with.
PURE_DEPS=(trimesh emcee pyserial jaxtyping wadler_lindig imageio tqdm beartype)

while [[ $# -gt 0 ]]; do
    case "$1" in
        --fetch-wheels)
            mkdir -p "$WHEELS"
            "$PY" -m pip download --no-deps --only-binary=:all: -d "$WHEELS" "${PURE_DEPS[@]}"
            "$PY" -m pip download --no-deps --only-binary=:all: -d "$WHEELS/warp" "warp-lang>=1.19"
            ls -l "$WHEELS" "$WHEELS/warp"
            exit 0
            ;;
        --split-warp)
            # Warp's wheel -> DIR/warp-py.tar.xz (the Python package without warp-clang, tests,
            # examples) and DIR/warp.so.xz.NN (its CUDA library in 45 MiB parts).
            out=$2
            mkdir -p "$out" /tmp/fovjax-warp-split
            "$PY" -m pip download --no-deps --only-binary=:all: -d /tmp/fovjax-warp-split "warp-lang>=1.19"
            rm -rf /tmp/fovjax-warp-split/x && mkdir /tmp/fovjax-warp-split/x
            (cd /tmp/fovjax-warp-split/x && "$PY" -m zipfile -e ../warp_lang-*.whl .)
            x=/tmp/fovjax-warp-split/x
            xz -T0 -6 -c "$x/warp/bin/warp.so" | split -b 45M -d - "$out/warp.so.xz."
            rm -rf "$x/warp/bin" "$x/warp/tests" "$x/warp/examples"
            tar -C "$x" -cJf "$out/warp-py.tar.xz" .
            ls -l "$out"
            exit 0
            ;;
        --warp-cache) MAKE_CACHE=1 ;;
        --arch) ARCH=$2; shift ;;
        --total) TOTAL=$2; shift ;;
        --dry-run) TINY=1; INSTALL=0 ;;  # --tiny --no-install
        --tiny) TINY=1 ;;
        --all) ALL=1 ;;
        --limit) LIMIT=$2; shift ;;
        --out) OUTDIR=$2; shift ;;
        --warp-parts) WARP_PARTS=$2; shift ;;
        --no-install) INSTALL=0 ;;
        --warp-only) WARP_ONLY=1 ;;
        --wheels) WHEELS=$2; shift ;;
        *) echo "gpu.sh: unknown option $1 (expected --fetch-wheels, --split-warp DIR, --warp-cache, --arch N, --dry-run, --tiny, --no-install, --warp-only, --all, --limit S, --total S, --out DIR, --warp-parts DIR, --wheels DIR)" >&2; exit 2 ;;
    esac
    shift
done

if [[ $MAKE_CACHE == 1 ]]; then
    # Warp's modules (the integrator's kernel, the mesh id, the ray queries) compiled for sm_$ARCH,
    # as PTX and as CUBIN, into $WARP_CACHE: no GPU needed.
    WARP_CACHE_PATH="$PWD/$WARP_CACHE" PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" "$PY" -c "
from fovjax.render._warp_whitted import compile_ahead
for path in compile_ahead($ARCH):
    print(path)
"
    du -sh "$WARP_CACHE"
    exit 0
fi

# step LIMIT COMMAND...: COMMAND stopped at LIMIT seconds or at what is left of --total.
step() {
    local limit=$1
    shift
    local left=$((TOTAL - (SECONDS - START)))
    if ((left < 20)); then
        echo "gpu.sh: skipped, the --total of $TOTAL s is spent: $*"
        return 0
    fi
    ((limit > left)) && limit=$left
    timeout "$limit" "$@" || echo "gpu.sh: failed or stopped (exit $?, limit $limit s): $*"
}

date -u +"%Y-%m-%d %H:%M UTC"
if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
else
    echo "nvidia-smi not found"
fi

if [[ -n $WARP_PARTS ]]; then
    site=/tmp/fovjax-warp-site
    rm -rf "$site" && mkdir -p "$site"
    tar -C "$site" -xJf "$WARP_PARTS/warp-py.tar.xz"
    mkdir -p "$site/warp/bin"
    cat "$WARP_PARTS"/warp.so.xz.* | xz -d > "$site/warp/bin/warp.so"
    export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}"
    echo "warp from $WARP_PARTS: $(du -sh "$site" | cut -f1)"
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

marker=$(mktemp)
if [[ -d $WARP_CACHE ]]; then
    export WARP_CACHE_PATH="$PWD/$WARP_CACHE"
    echo "Warp's kernels from $WARP_CACHE (made by --warp-cache)"
fi
if [[ $TINY == 1 ]]; then
    # A check of the script, not figures: no benchmark writes a record (benchmarks/_record.py).
    export FOVJAX_BENCH_RECORD=0
    warp_args=(--width 64 --height 48 --random 4096 --repeats 1)
    trace_args=(--width 64 --height 48 --random 4096 --repeats 1 --rows primary random --peers)
    fov_args=(--size 64 48 --speedup --spp 1 --repeats 1)
    frame_args=(--dry-run)
else
    # One ray per pixel of both eyes (2 x 1280 x 1024 = 2560 x 1024), 2M random rays; no CPU peers.
    warp_args=(--width 2560 --height 1024 --random 2097152 --repeats 3 --warp-bvh sah lbvh)
    trace_args=(--width 2560 --height 1024 --random 2097152 --repeats 3 --peers)
    fov_args=(--full --speedup --spp 1 --repeats 3)
    frame_args=(--repeats 5)
fi
have_warp=0
"$PY" -c "import warp" 2>/dev/null && have_warp=1

if [[ $have_warp == 1 && $TINY == 0 ]]; then
    echo
    echo "== the Warp tests on this machine's default JAX device (queries, the integrator) =="
    step 180 env FOVJAX_TEST_FAST_COMPILE=0 "$PY" -m pytest -q -p no:cacheprovider -n 0 \
        tests/test_trace_warp.py tests/test_render_warp.py
fi

if [[ $WARP_ONLY == 0 ]]; then
    echo
    echo "== stereo frames with the Warp integrator, and a profile of a full and a foveated frame =="
    if [[ $have_warp == 0 ]]; then
        echo "gpu.sh: warp-lang is not installed: the frames below run the JAX integrator on a GPU"
    fi
    step 240 "$PY" benchmarks/warp_frame.py "${frame_args[@]}"
fi

echo
echo "== Warp and JAX backends, the atrium's primary, random and shadow rays (Mrays/s) =="
if [[ $have_warp == 1 ]]; then
    step "$LIMIT" "$PY" benchmarks/trace_warp.py "${warp_args[@]}"
else
    echo "gpu.sh: warp-lang is not installed (pip install 'fovjax[gpu]', --fetch-wheels or --warp-parts): no Warp rows"
fi

if [[ $WARP_ONLY == 0 && $ALL == 1 ]]; then
    echo
    echo "== foveated vs full stereo frames, gaze off-centre (ms per frame) =="
    step "$LIMIT" "$PY" benchmarks/foveation.py "${fov_args[@]}"
    echo
    echo "== ray queries against the CPU peers (Mrays/s) =="
    step "$LIMIT" "$PY" benchmarks/trace_throughput.py "${trace_args[@]}"
fi

if [[ -n ${WARP_CACHE_PATH:-} ]]; then
    compiled=$(find "$WARP_CACHE_PATH" -newer "$marker" \( -name '*.ptx' -o -name '*.cubin' \) | wc -l)
    echo "Warp modules compiled here despite $WARP_CACHE: $compiled"
fi
echo "gpu.sh: $((SECONDS - START)) s"

if [[ -n $OUTDIR ]]; then
    mkdir -p "$OUTDIR"
    find benchmarks/results -name '*.json' -newer "$marker" -exec cp {} "$OUTDIR"/ \;
    ls "$OUTDIR"
fi
