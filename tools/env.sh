# Source this file for a shell with the project's environment: the venv first on PATH, the catkin
# workspace's devel space, and ROS logs kept inside the checkout.  (bash: `source tools/env.sh`)
_AGIPRO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
_agipro_nounset=$([[ $- == *u* ]] && echo 1 || echo 0)
set +u
export PATH="$_AGIPRO_ROOT/.venv/bin:$PATH"
export VIRTUAL_ENV="$_AGIPRO_ROOT/.venv"
# shellcheck disable=SC1091
export AGIPROBOT_WS="$(bash "$_AGIPRO_ROOT/tools/workspace_path.sh")"
source "$AGIPROBOT_WS/devel/setup.bash"
export ROS_HOME="${ROS_HOME:-$_AGIPRO_ROOT/.ros_home}"
export ROS_LOG_DIR="${ROS_LOG_DIR:-$ROS_HOME/log}"
export ROS_MASTER_URI="${ROS_MASTER_URI:-http://127.0.0.1:11311}"
export ROS_HOSTNAME="${ROS_HOSTNAME:-127.0.0.1}"
export PYTHONDONTWRITEBYTECODE=1
[ "$_agipro_nounset" = 1 ] && set -u
unset _agipro_nounset
