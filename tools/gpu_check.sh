#!/usr/bin/env bash
# The prepared GPU check: `warp-terrain gpu-check` on a machine with a GPU that reaches no
# package index (README, "Benchmarks").
#
# Such a machine has python3 with torch, numpy and most of our dependencies, but not warp-lang,
# usd-core, hydra-core, omegaconf or antlr4-python3-runtime (omegaconf's parser). Those travel
# as wheels for its Python (DEVICE_PYTHON, default 3.12), pinned to the versions installed here.
# warp-lang's wheel alone (~150 MB) is larger than what one call can carry beside the working
# tree (64 MiB in all), so the wheels travel as one tar cut into parts of one size, as large as
# fit beside the working tree (at most 58 MiB; PART_MIB sets it): one part per call, each stored on the machine under /tmp, reassembled and checked (sha256)
# once all are there.
#
#   here:        bash tools/gpu_check.sh prepare
#                -> .whl/part-1 ... .whl/part-N (git-ignored through .git/info/exclude)
#   the machine: bash tools/gpu_check.sh device [gpu-check options]
#                once per part, carrying .whl/part-K (K = 1..N), calls close enough that the
#                machine stays the same; the call that brings the last part installs the wheels
#                (once), installs this working tree (each time: the checkout as it travelled),
#                and runs `warp-terrain gpu-check --json "$OUT/gpu_check.json"` with the options
#                given (e.g. --quick, --time-limit 300), its output also in $OUT/gpu_check.log.
#                A later call with the parts already stored runs the check again at once.
#
# Exit status: gpu-check's (0: nothing FAILed, 1: something did), 0 while parts are missing,
# 2 when nothing was carried or the parts do not reassemble.
set -euo pipefail
cd "$(dirname "$0")/.."

STAGE=${GPU_CHECK_STAGE:-/tmp/warp-terrain-gpu-check}
CARRY_MIB=64  # what one call of the device tool carries: the working tree and the carried paths
DEVICE_PYTHON=${DEVICE_PYTHON:-3.12}
PLATFORMS=(--platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)

prepare() {
    local py=${PYTHON:-.venv/bin/python}
    [ -x "$py" ] || py=python3
    version() { "$py" -c "from importlib.metadata import version; print(version('$1'))"; }
    local warp usd hydra omegaconf antlr
    warp=$(version warp-lang); usd=$(version usd-core); hydra=$(version hydra-core)
    omegaconf=$(version omegaconf); antlr=$(version antlr4-python3-runtime)
    local git_dir
    git_dir=$(git rev-parse --git-dir)
    mkdir -p "$git_dir/info"
    grep -qxF '/.whl/' "$git_dir/info/exclude" 2>/dev/null || echo '/.whl/' >> "$git_dir/info/exclude"
    rm -rf .whl
    mkdir -p .whl/wheels
    "$py" -m pip download -q --disable-pip-version-check --no-deps --only-binary=:all: --python-version "$DEVICE_PYTHON" \
        --implementation cp "${PLATFORMS[@]}" -d .whl/wheels \
        "warp-lang==$warp" "usd-core==$usd" "hydra-core==$hydra" "omegaconf==$omegaconf"
    # antlr4-python3-runtime 4.9.x (what omegaconf 2.3 pins) comes as source only: pure Python, built here
    "$py" -m pip wheel -q --disable-pip-version-check --no-deps -w .whl/wheels "antlr4-python3-runtime==$antlr"
    tar -C .whl -cf .whl/bundle.tar wheels
    # each call carries the working tree too: parts as large as fit beside it, all of one size
    local sha n k=0 total tree part_mib
    sha=$(sha256sum .whl/bundle.tar | cut -d' ' -f1)
    total=$(stat -c %s .whl/bundle.tar)
    tree=$(git ls-files -z --cached --others --exclude-standard | du --files0-from=- -cb 2>/dev/null | tail -1 | cut -f1)
    part_mib=${PART_MIB:-$(( (CARRY_MIB * 1048576 - tree) / 1048576 - 1 ))}
    [ "$part_mib" -gt 58 ] && [ -z "${PART_MIB:-}" ] && part_mib=58
    if [ "$part_mib" -lt 8 ]; then
        echo "gpu_check: the working tree ($((tree / 1048576)) MiB) leaves too little of the $CARRY_MIB MiB a call carries" >&2
        exit 2
    fi
    n=$(( (total + part_mib * 1048576 - 1) / (part_mib * 1048576) ))
    split -n "$n" -d -a 2 .whl/bundle.tar .whl/bundle.tar.
    for f in $(find .whl -maxdepth 1 -name 'bundle.tar.[0-9][0-9]' | sort); do
        k=$((k + 1))
        mkdir -p ".whl/part-$k"
        mv "$f" ".whl/part-$k/"
        printf '%s %s\n' "$sha" "$n" > ".whl/part-$k/MANIFEST"
    done
    echo "wheels for Python $DEVICE_PYTHON:"
    tar -tf .whl/bundle.tar | sed -n 's|^wheels/\(.*\.whl\)$|  \1|p'
    rm -rf .whl/wheels .whl/bundle.tar
    echo "$n part(s) of $(( (total / n + 1048575) / 1048576 )) MiB (working tree $(( (tree + 1048575) / 1048576 )) MiB); on the machine, one call per part:"
    for k in $(seq 1 "$n"); do
        echo "  bash tools/gpu_check.sh device      carrying .whl/part-$k"
    done
    echo "(the call that brings the last part runs the check, up to its time limit plus the install: allow 10 minutes;"
    echo " gpu-check options go after 'device', e.g. --time-limit 300)"
}

device() {
    local py=${PYTHON:-python3}
    mkdir -p "$STAGE/parts"
    local carried=0 d
    for d in .whl/part-*; do
        [ -f "$d/MANIFEST" ] || continue
        if [ -f "$STAGE/MANIFEST" ] && ! cmp -s "$d/MANIFEST" "$STAGE/MANIFEST"; then
            echo "gpu_check: $d belongs to another bundle than the parts stored before: starting over"
            rm -rf "$STAGE/parts" "$STAGE/site" "$STAGE/installed"
            mkdir -p "$STAGE/parts"
        fi
        cp "$d"/bundle.tar.[0-9][0-9] "$STAGE/parts/"
        cp "$d/MANIFEST" "$STAGE/MANIFEST"
        carried=$((carried + 1))
    done
    if [ ! -f "$STAGE/MANIFEST" ]; then
        echo "gpu_check: no wheel parts carried or stored: run 'bash tools/gpu_check.sh prepare' here and carry .whl/part-1" >&2
        exit 2
    fi
    local sha n have
    read -r sha n < "$STAGE/MANIFEST"
    have=$(find "$STAGE/parts" -name 'bundle.tar.[0-9][0-9]' | wc -l)
    if [ "$have" -lt "$n" ]; then
        echo "gpu_check: $have of $n part(s) stored in $STAGE (this call carried $carried); call again carrying:"
        local k
        for k in $(seq 1 "$n"); do
            [ -f "$STAGE/parts/bundle.tar.$(printf '%02d' $((k - 1)))" ] || echo "  .whl/part-$k"
        done
        exit 0
    fi
    if [ ! -f "$STAGE/installed" ]; then
        cat "$STAGE"/parts/bundle.tar.[0-9][0-9] > "$STAGE/bundle.tar"
        if ! echo "$sha  $STAGE/bundle.tar" | sha256sum -c --quiet; then
            echo "gpu_check: the parts do not reassemble (sha256 mismatch): prepare again and carry every part" >&2
            rm -rf "$STAGE"
            exit 2
        fi
        rm -rf "$STAGE/wheels" "$STAGE/site"
        tar -C "$STAGE" -xf "$STAGE/bundle.tar"
        rm -f "$STAGE/bundle.tar"
        "$py" -m pip install -q --disable-pip-version-check --no-index --no-deps --no-compile --no-cache-dir --target "$STAGE/site" "$STAGE"/wheels/*.whl
        touch "$STAGE/installed"
    fi
    # this working tree, as it travelled (warp_terrain.kernels is kernels/: only an install maps it)
    rm -rf "$STAGE/wt"
    "$py" -m pip install -q --disable-pip-version-check --no-index --no-deps --no-build-isolation --no-compile --target "$STAGE/wt" .
    local out=${OUT:-$PWD/gpu-check-out}
    mkdir -p "$out"
    out=$(cd "$out" && pwd)
    OUT=$out
    export PYTHONPATH="$STAGE/wt:$STAGE/site${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
    cd "$STAGE"  # not the checkout, whose warp_terrain/ would shadow the installed package
    set +e -o pipefail
    "$py" -m warp_terrain.cli gpu-check --json "$OUT/gpu_check.json" "$@" 2>&1 | tee "$OUT/gpu_check.log"
    local status=$?
    echo "gpu_check: exit status $status; report in $OUT/gpu_check.json, log in $OUT/gpu_check.log"
    exit "$status"
}

case "${1:-}" in
    prepare) shift; prepare "$@" ;;
    device) shift; device "$@" ;;
    *) echo "usage: bash tools/gpu_check.sh prepare | device [gpu-check options]" >&2; exit 2 ;;
esac
