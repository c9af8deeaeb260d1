#!/usr/bin/env bash
# Fetch MuJoCo 3.17.0 (shared library + headers) and the Kinova Jaco / Duplo assets of dm_control 1.0.50
# from PyPI wheels into the git-ignored `third_party/` folder. Nothing is pip-installed.
#
# Idempotent: a second run checks a stamp file and returns at once.
#
# Layout afterwards:
#   third_party/mujoco/lib/libmujoco.so.3.17.0, libmujoco.so -> libmujoco.so.3.17.0
#   third_party/mujoco/include/mujoco/*.h
#   third_party/assets/kinova/{jaco_arm.xml, jaco_hand.xml, common.xml, meshes_decimated/*.stl}
#   third_party/assets/duplo/duplo2x4.xml
#
# Licences: MuJoCo and dm_control are Apache-2.0; the Kinova MJCF and meshes are BSD-3-Clause
# (c) 2017 Kinova Robotics, modified (c) 2018 the dm_control authors (the wheel omits that LICENSE file).
set -euo pipefail

MUJOCO_VERSION=3.17.0
DM_CONTROL_VERSION=1.0.50
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
TP="$ROOT/third_party"
STAMP="$TP/.setup-mujoco-$MUJOCO_VERSION-dm_control-$DM_CONTROL_VERSION"

if [[ -f "$STAMP" && -e "$TP/mujoco/lib/libmujoco.so" && -f "$TP/assets/kinova/jaco_arm.xml" ]]; then
    echo "setup-mujoco: already set up in $TP"
    exit 0
fi

mkdir -p "$TP/wheels"
fetch() {
    local spec="$1" pattern="$2"
    if ! compgen -G "$TP/wheels/$pattern" >/dev/null; then
        echo "setup-mujoco: downloading $spec" >&2
        python3 -m pip download --no-deps --only-binary=:all: --platform manylinux_2_28_x86_64 \
            --python-version 3.12 --implementation cp -d "$TP/wheels" "$spec" >/dev/null
    fi
    compgen -G "$TP/wheels/$pattern" | head -n1
}

MJ_WHEEL="$(fetch "mujoco==$MUJOCO_VERSION" "mujoco-$MUJOCO_VERSION-*.whl")"
DM_WHEEL="$(fetch "dm_control==$DM_CONTROL_VERSION" "dm_control-$DM_CONTROL_VERSION-*.whl")"

extract() {
    # extract WHEEL DEST PATTERN... : unzip selected members into a scratch folder
    local wheel="$1" dest="$2"
    shift 2
    rm -rf "$dest"
    mkdir -p "$dest"
    python3 - "$wheel" "$dest" "$@" <<'PY'
import fnmatch, sys, zipfile
wheel, dest, pats = sys.argv[1], sys.argv[2], sys.argv[3:]
with zipfile.ZipFile(wheel) as z:
    names = [n for n in z.namelist() if any(fnmatch.fnmatch(n, p) for p in pats)]
    if not names:
        sys.exit(f"no member of {wheel} matches {pats}")
    z.extractall(dest, names)
PY
}

SCRATCH="$TP/.scratch"
extract "$MJ_WHEEL" "$SCRATCH/mj" "mujoco/libmujoco.so*" "mujoco/include/*"
rm -rf "$TP/mujoco"
mkdir -p "$TP/mujoco/lib" "$TP/mujoco/include"
cp "$SCRATCH/mj/mujoco/libmujoco.so.$MUJOCO_VERSION" "$TP/mujoco/lib/"
cp -r "$SCRATCH/mj/mujoco/include/." "$TP/mujoco/include/"
ln -sf "libmujoco.so.$MUJOCO_VERSION" "$TP/mujoco/lib/libmujoco.so"

extract "$DM_WHEEL" "$SCRATCH/dm" "dm_control/third_party/kinova/*" "dm_control/entities/props/duplo/*"
rm -rf "$TP/assets"
mkdir -p "$TP/assets"
cp -r "$SCRATCH/dm/dm_control/third_party/kinova" "$TP/assets/kinova"
cp -r "$SCRATCH/dm/dm_control/entities/props/duplo" "$TP/assets/duplo"
rm -rf "$SCRATCH"

touch "$STAMP"
echo "setup-mujoco: MuJoCo $MUJOCO_VERSION in $TP/mujoco/lib, assets in $TP/assets"
