#!/usr/bin/env bash
# One idempotent install of the workspace into ./.venv, with no ROS installed beforehand:
#   1. a Python 3.11 virtual environment with the pinned ROS 2 Jazzy wheels, torch (CPU wheel on
#      disk), OpenCV contrib and the other libraries (requirements.txt + constraints.txt);
#   2. the interface package msg_defs/ built with CMake/rosidl into the venv prefix, so that
#      `import stereo_vehicle_msgs.msg` works with no sourcing; likewise tf2_msgs and
#      vision_msgs from third_party_msgs/ (upstream's definitions) when not installed;
#   3. the node packages under src/ installed in editable mode, so their console scripts run;
#   4. the detector's pretrained weights (npm package @vladmandic/human 3.3.6, pinned by version
#      and sha512, scripts/fetch_pretrained.sh) into .venv/pretrained; only re-training the
#      detector and its conversion test need them (skip with SETUP_PRETRAINED=0).
# Every step records a hash of its inputs and is skipped when nothing changed: a second run
# takes a few seconds. Usage: scripts/setup.sh [--force]
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
STAMPS="$VENV/.setup-stamps"
PY="${PYTHON:-python3.11}"
FORCE=0
[ "${1:-}" = "--force" ] && FORCE=1

log() { printf '[setup] %s\n' "$*" >&2; }
# pip, quiet, without the machine's notes about local index folders that do not exist
pip_install() {
  PIP_CONSTRAINT= python -m pip install --disable-pip-version-check -q "$@" 2>&1 \
    | { grep -v "is ignored: it is neither a file nor a directory" || true; }
  return "${PIPESTATUS[0]}"
}
die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }

# hash of the given files/directories' contents (paths relative to ROOT)
inputs_hash() {
  (cd "$ROOT" && find "$@" -type f ! -path '*/__pycache__/*' ! -name '*.pyc' ! -path '*.egg-info*' \
      -print0 | sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1)
}
step_done() { [ "$FORCE" = 0 ] && [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
mark_done() { mkdir -p "$STAMPS" && printf '%s' "$2" > "$STAMPS/$1"; }

command -v "$PY" >/dev/null 2>&1 || die "$PY not found: the ROS 2 Jazzy wheels need CPython 3.11"

# 1. virtual environment and Python packages
if [ ! -x "$VENV/bin/python" ]; then
  log "creating $VENV"
  "$PY" -m venv "$VENV"
fi
# shellcheck disable=SC1091
source "$VENV/bin/activate"
h=$(inputs_hash requirements.txt constraints.txt)
if ! step_done pip "$h"; then
  log "installing Python packages (ROS 2 Jazzy wheels, torch CPU, OpenCV contrib, ...)"
  # constraints.txt pins every transitive version; PIP_CONSTRAINT from the machine would
  # conflict with it, so only ours applies here.
  pip_install -r "$ROOT/requirements.txt" -c "$ROOT/constraints.txt"
  mark_done pip "$h"
fi

# 1b. benchmark-only packages whose declared pins conflict with ours (pure-ab-3d-mot pins
#     numpy<=2.3.4 and runs on ours): installed without their dependencies, versions pinned
BENCH_NODEPS="pure-ab-3d-mot==2.2.0 association-quality-clavia==0.3.2"
if ! step_done bench_nodeps "$BENCH_NODEPS"; then
  log "installing benchmark packages: $BENCH_NODEPS"
  # shellcheck disable=SC2086
  pip_install --no-deps $BENCH_NODEPS
  mark_done bench_nodeps "$BENCH_NODEPS"
fi

# 2. interface packages (rosidl) into the venv prefix: msg_defs, and the upstream interface
#    packages the nodes also publish (third_party_msgs/: tf2_msgs, vision_msgs) where they are
#    not installed already (a full ROS install has them; colcon never sees these copies)
export AMENT_PREFIX_PATH="$VENV"
# The wheels' exported CMake files hard-code the wheel builder's Python and numpy include
# directories; point them at this interpreter's (see ../shared/notes/ros2-from-pip.md).
fix_exported_includes() {
  local py_inc np_inc f
  py_inc=$(python -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  np_inc=$(python -c 'import numpy; print(numpy.get_include())')
  for f in "$VENV"/share/*/cmake/export_*__rosidl_generator_pyExport.cmake; do
    [ -f "$f" ] || continue
    sed -i -E \
      -e "s#/opt/python/cp311-cp311/include/python3\.11#${py_inc}#g" \
      -e "s#[^;\"]*/site-packages/numpy/(_core|core)/include#${np_inc}#g" "$f"
  done
}
# build_interfaces DIR PACKAGE: CMake/rosidl build of the interface package in DIR into the venv
build_interfaces() {
  local src="$1" name="$2" build="$VENV/.build/$(basename "$1")"
  fix_exported_includes
  rm -rf "$build" && mkdir -p "$build"
  cmake -S "$src" -B "$build" -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_INSTALL_PREFIX="$VENV" -DBUILD_TESTING=OFF \
      -DPython3_EXECUTABLE="$VENV/bin/python" >"$build.log" 2>&1 \
    || { tail -n 30 "$build.log" >&2; die "cmake configure of $name failed (log: $build.log)"; }
  cmake --build "$build" -j "$(nproc)" >>"$build.log" 2>&1 \
    || { tail -n 30 "$build.log" >&2; die "build of $name failed (log: $build.log)"; }
  cmake --install "$build" >>"$build.log" 2>&1 \
    || { tail -n 30 "$build.log" >&2; die "install of $name failed (log: $build.log)"; }
  python -c "import $name.msg" || die "$name built but does not import"
}
h=$(inputs_hash msg_defs requirements.txt constraints.txt)
if ! step_done msgs "$h"; then
  log "building msg_defs (stereo_vehicle_msgs) into the venv"
  build_interfaces "$ROOT/msg_defs" stereo_vehicle_msgs
  mark_done msgs "$h"
fi
for pkg in tf2_msgs vision_msgs; do
  h=$(inputs_hash "third_party_msgs/$pkg" requirements.txt constraints.txt)
  step_done "msgs_$pkg" "$h" && continue
  # installed by someone else (a sourced ROS install): use it, never shadow it
  if [ ! -f "$STAMPS/msgs_$pkg" ] && python -c "import $pkg.msg" 2>/dev/null; then
    log "$pkg: using the installed package ($(python -c "import $pkg; print($pkg.__path__[0])"))"
    continue
  fi
  log "building $pkg (not installed: third_party_msgs/$pkg, upstream's definitions) into the venv"
  build_interfaces "$ROOT/third_party_msgs/$pkg" "$pkg"
  mark_done "msgs_$pkg" "$h"
done

# 3. node packages (editable: the console scripts run the working tree's code)
pkgs=(src/*/setup.py)
touch "$VENV/COLCON_IGNORE"
h=$(inputs_hash "${pkgs[@]}" $(ls src/*/package.xml src/*/setup.cfg 2>/dev/null))
if ! step_done nodes "$h"; then
  log "installing node packages: $(dirname "${pkgs[@]}" | xargs -n1 basename | tr '\n' ' ')"
  args=()
  for p in "${pkgs[@]}"; do args+=(-e "$ROOT/$(dirname "$p")"); done
  pip_install --no-deps --no-build-isolation "${args[@]}"
  mark_done nodes "$h"
fi
# 4. pretrained detector weights (a registry package pinned by version and hash)
if [ "${SETUP_PRETRAINED:-1}" != 0 ]; then
  bash "$ROOT/scripts/fetch_pretrained.sh" "$VENV/pretrained"
fi
log "ready: $VENV (activate with: source .venv/bin/activate)"
