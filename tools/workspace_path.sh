# Prints the catkin workspace of this checkout. It lives outside the repository (rosrun and roslaunch search
# the package directory recursively and would find a nested workspace's copies of every executable), one
# per checkout: override with AGIPROBOT_WS.
_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
echo "${AGIPROBOT_WS:-${XDG_CACHE_HOME:-$HOME/.cache}/agiprobot_measurement/ws-$(basename "$_root")-$(printf '%s' "$_root" | sha256sum | cut -c1-8)}"
unset _root
