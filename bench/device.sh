#!/usr/bin/env bash
# Frame times on a real GPU (issue 49): one script, run first whenever a device machine is lent.
#
#   bash bench/device.sh --prepare   # here (network): .device/ = EGL's loader libraries and the
#                                    # Python packages the device's image lacks, for Python 3.12
#   bash bench/device.sh             # there (no network): set up, check EGL gives the NVIDIA
#                                    # renderer (fail fast if not), run bench/bench_device.py
#   bash bench/device.sh --dry-run   # here: the same steps at tiny sizes on llvmpipe, through
#                                    # the project's .venv (`make setup`), and the JSON checked
#   extra arguments go to bench/bench_device.py (--only STEP,..., --budget-s S)
#
# Results: $OUT/device.json (every step's figures, the GPU, driver and GL strings) and
# $OUT/device.log (every step's output); OUT defaults to out/device (out/device-dry for --dry-run).
# The device machine reaches no network: what it needs travels in .device/ (in .gitignore,
# named in the device tool's `carry`), 64 MiB with the working tree.
set -euo pipefail
cd "$(dirname "$0")/.."

MODE=run
if [ "${1:-}" = "--prepare" ] || [ "${1:-}" = "--dry-run" ]; then MODE=${1#--}; shift; fi

# The packages the device's image (python3 3.12 with numpy, scipy, OpenCV, Pillow, numba, h5py,
# lxml...) lacks and the benchmarks import, at the versions `make setup` installed here.
CARRY_PACKAGES="affine av cligj click-plugins DracoPy fastcrc geopandas glcontext ijson mapbox_earcut
moderngl osmium owslib pmtiles pygeomag pymavlink PyOpenGL pyproj rasterio shapely trimesh xyzservices"
# EGL through libglvnd (the NVIDIA driver brings its vendor library, not the loader).
GL_DEBS="libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2"
DEVICE_PYTHON=3.12

prepare() {
    [ -x .venv/bin/python ] || make setup
    rm -rf .device && mkdir -p .device/gl .device/wheels
    local lists=/tmp/geofuse-apt-lists
    mkdir -p "$lists/partial"
    local o="-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=$lists"
    # shellcheck disable=SC2086
    apt-get $o update -qq
    # shellcheck disable=SC2086
    (cd .device/gl && apt-get $o download $GL_DEBS)
    local pins=()
    for p in $CARRY_PACKAGES; do
        pins+=("$(.venv/bin/python -m pip freeze | grep -i "^${p//_/[-_]}==")")
    done
    python3 -m pip download --quiet --no-deps --only-binary=:all: --implementation cp \
        --python-version "$DEVICE_PYTHON" --platform manylinux_2_28_x86_64 \
        --platform manylinux_2_27_x86_64 --platform manylinux_2_24_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        --platform manylinux1_x86_64 --platform any -d .device/wheels "${pins[@]}"
    local site=/tmp/geofuse-device-build
    rm -rf "$site" && mkdir -p "$site"
    for w in .device/wheels/*.whl; do python3 -m zipfile -e "$w" "$site"; done
    # What no benchmark loads: the wheels' C headers, MAVLink dialects other than the ones
    # pymavlink's mavutil opens (`all` by default, ardupilotmega where asked; common, minimal and
    # standard beside them) and their XML; and the extension modules' symbol tables (strip).
    rm -rf "$site"/*.data
    find "$site/pymavlink/dialects" -type f ! -name '__init__.py' ! -name ardupilotmega.py \
        ! -name common.py ! -name minimal.py ! -name standard.py ! -name all.py -delete
    find "$site" -name '*.so' -type f -exec strip --strip-unneeded {} +
    # Nor the packages' own tests, type stubs or command-line tools.
    find "$site" -type d -name tests -prune -exec rm -rf {} +
    find "$site" -name '*.pyi' -delete
    rm -rf "$site/moderngl-stubs" "$site/pymavlink/tools"
    # Mostly x86 machine code (the wheels' shared libraries): xz's x86 filter and a dictionary as
    # large as the whole tar take 8 % off (44 MB against 48), what keeps it within the carry limit.
    tar -C "$site" --sort=name -cf - . |
        xz --x86 --lzma2=preset=9,dict=192MiB -T0 >.device/site.tar.xz
    rm -rf .device/wheels "$site"
    du -sh .device/site.tar.xz .device/gl
    local tree device
    tree=$(git ls-files -co --exclude-standard -z | du -cb --files0-from=- | tail -1 | cut -f1)
    device=$(du -sb .device | cut -f1)
    echo "carry .device with the device tool: $(((tree + device) >> 20)) MiB travel with the" \
        "working tree ($((tree >> 20)) MiB); the limit is 64 MiB"
}

setup_device() {
    # EGL's loader from the carried packages (the device README's recipe), then the driver's
    # vendor file where glvnd would not find it on its own.
    if compgen -G ".device/gl/*.deb" >/dev/null; then
        for f in .device/gl/*.deb; do dpkg -x "$f" /; done
        ldconfig
    fi
    local nv=/usr/local/nvidia
    if [ -f "$nv/share/glvnd/egl_vendor.d/10_nvidia.json" ] &&
        ! compgen -G "/usr/share/glvnd/egl_vendor.d/*nvidia*" >/dev/null; then
        export __EGL_VENDOR_LIBRARY_FILENAMES="$nv/share/glvnd/egl_vendor.d/10_nvidia.json"
    fi
    for d in "$nv/lib64" "$nv/lib"; do
        [ -d "$d" ] && export LD_LIBRARY_PATH="$d${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
    done
    if [ -f .device/site.tar.xz ]; then
        local site=/tmp/geofuse-device-site
        if [ ! -f "$site/.unpacked" ]; then
            rm -rf "$site" && mkdir -p "$site"
            tar -C "$site" -xJf .device/site.tar.xz
            touch "$site/.unpacked"
        fi
        export PYTHONPATH="$site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
        PY=python3
    else # a machine with a network: the project's own environment
        make setup
        PY=.venv/bin/python
    fi
    # What EGL will find, said before anything depends on it.
    echo "EGL vendors: $(ls /usr/share/glvnd/egl_vendor.d/ 2>/dev/null | tr '\n' ' ')" \
        "${__EGL_VENDOR_LIBRARY_FILENAMES:-}; libEGL: $(ldconfig -p | grep -c 'libEGL')"
    if command -v nvidia-smi >/dev/null; then
        nvidia-smi --query-gpu=name,driver_version --format=csv
    fi
    "$PY" --version
}

case "$MODE" in
prepare)
    prepare
    ;;
dry-run)
    [ -x .venv/bin/python ] || make setup
    OUT=${OUT:-out/device-dry}
    mkdir -p "$OUT"
    rm -f "$OUT/device.log"
    .venv/bin/python bench/bench_device.py --dry-run --out "$OUT/device.json" \
        --log "$OUT/device.log" --budget-s 300 "$@"
    ;;
run)
    OUT=${OUT:-out/device}
    mkdir -p "$OUT"
    rm -f "$OUT/device.log"
    setup_device
    export PYTHONUNBUFFERED=1
    "$PY" bench/bench_device.py --require-gpu --out "$OUT/device.json" \
        --log "$OUT/device.log" "$@"
    ;;
esac
