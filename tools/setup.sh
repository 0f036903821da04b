#!/usr/bin/env bash
# One idempotent set-up: Debian packages, the .venv, pinned pip requirements, the catkin workspace (.ws) and
# its build. Each step checks first and does nothing when already done, so a second run takes seconds.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
log() { printf '[setup] %s\n' "$*"; }

# 1. Debian packages
mapfile -t PKGS < <(grep -v '^\s*#' tools/apt-packages.txt | grep -v '^\s*$')
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  log "installing ${#missing[@]} Debian packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
else
  log "Debian packages: all present"
fi

# 2. venv from Debian's interpreter (sees rospy, PyKDL, tf2 from /usr/lib/python3/dist-packages)
if [ ! -x .venv/bin/python3 ]; then
  log "creating .venv from /usr/bin/python3"
  /usr/bin/python3 -m venv --system-site-packages .venv
fi
REQ_HASH="$(sha256sum requirements.txt | cut -d' ' -f1)"
if [ "$(cat .venv/.requirements.sha256 2>/dev/null)" != "$REQ_HASH" ]; then
  log "installing pinned requirements"
  .venv/bin/pip install --disable-pip-version-check -q -r requirements.txt 2>&1 | grep -v "is ignored: it is neither" || true
  .venv/bin/python3 -c "import numpy, scipy, trimesh, fcl, ompl, toppra, pulp, cv2, PyKDL, rospy" \
    || { log "ERROR: the venv cannot import its dependencies"; exit 1; }
  echo "$REQ_HASH" > .venv/.requirements.sha256
else
  log "pip requirements: up to date"
fi

# 3. catkin workspace (outside the checkout, see tools/workspace_path.sh) with the repository in src/
WS="$(bash tools/workspace_path.sh)"
mkdir -p "$WS/src"
[ "$(readlink "$WS/src/agiprobot_measurement")" = "$ROOT" ] || ln -sfn "$ROOT" "$WS/src/agiprobot_measurement"
# The interface packages of packages/ (phoxi_camera, asr_robot_model_services, control_msgs, ...): catkin does not look for packages
# inside another package's folder, so each gets its own link beside the repository's.
# A machine that has the real package (ROS Noetic's control_msgs, a MoveIt install's moveit_msgs, a driver's own
# workspace) keeps it: the carried copy is not linked there, since it would shadow the real one (for moveit_msgs, a
# subset, it would break MoveIt).
system_package() {  # prints where a package of that name is installed outside this checkout, if anywhere
  local name="$1" dir
  for dir in /usr/share /opt/ros/*/share; do
    [ -f "$dir/$name/package.xml" ] && { echo "$dir/$name"; return 0; }
  done
  return 1
}
for pkg_dir in "$ROOT"/packages/*/; do
  pkg_dir="${pkg_dir%/}"
  [ -f "$pkg_dir/package.xml" ] || continue
  name="$(basename "$pkg_dir")"
  link="$WS/src/$name"
  if real="$(system_package "$name")"; then
    log "not linking packages/$name: this machine has the real package at $real"
    [ -L "$link" ] && rm -f "$link"
    continue
  fi
  [ "$(readlink "$link")" = "$pkg_dir" ] || ln -sfn "$pkg_dir" "$link"
done
# First-build trap: without this folder catkin records an empty PYTHONPATH in setup_cached.sh.
mkdir -p "$WS/devel/lib/python3/dist-packages"

# Rebuild only when something that the build consumes changed (interfaces, CMake, package, entry points).
BUILD_HASH="$( { ls nodes scripts tools packages packages/*/nodes; cat CMakeLists.txt package.xml setup.py msg/* srv/* \
  action/* test/ros/*.test packages/*/CMakeLists.txt packages/*/package.xml packages/*/msg/* packages/*/srv/* \
  packages/*/srv/*/* packages/*/action/* 2>/dev/null || true; } | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$WS/.build.sha256" 2>/dev/null)" != "$BUILD_HASH" ] || [ ! -f "$WS/devel/setup.bash" ]; then
  log "building the catkin workspace $WS"
  set +u; export PATH="$ROOT/.venv/bin:$PATH"; set -u
  # genpy's msg/srv __init__.py imports every generated module in its folder: drop them so that the build writes
  # them again, and a type that moved to another package (or was removed) is not imported from a stale file.
  rm -rf "$WS"/devel/lib/python3/dist-packages/*/{msg,srv}
  # the same for catkin's devel-space relays of node scripts: a relay of a removed or moved node would shadow the
  # package that has it now (rosrun lists both); CMake writes the relays of the present ones again
  { grep -l "creates a relay to a python script source file" "$WS"/devel/lib/*/* 2>/dev/null || true; } | xargs -r rm -f
  catkin_make --force-cmake -C "$WS" -DPYTHON_EXECUTABLE="$ROOT/.venv/bin/python3" -DCATKIN_ENABLE_TESTING=ON \
    -DCMAKE_BUILD_TYPE=Release > "$WS/build.log" 2>&1 \
    || { tail -40 "$WS/build.log"; log "ERROR: catkin_make failed (full log: $WS/build.log)"; exit 1; }
  echo "$BUILD_HASH" > "$WS/.build.sha256"
else
  log "catkin workspace: up to date"
fi
log "ready (source tools/env.sh for a shell with this environment)"
