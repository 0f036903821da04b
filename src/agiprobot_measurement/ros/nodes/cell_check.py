"""The node ``cell_check`` (launched by nodes/cell_check, launch/cell_check.launch): waits until a real cell's drivers
offer what ``config/cell_interfaces.yaml`` lists for the chosen roles, naming what is still missing.

It asks the master every ``~check_period_s``: the published topics with their types, the services (each wanted one's
type read from its provider) and the wanted parameters (:class:`~agiprobot_measurement.station.cell_interfaces.MasterSnapshot`);
:func:`~agiprobot_measurement.station.cell_interfaces.missing_interfaces` says what is absent or of another type.
While something is missing it logs the list every ``~log_period_s``. Once nothing is: it logs "cell ready", publishes
true on the latched ``~ready`` (false until then) and keeps watching (something that goes away sets ``~ready`` false
again and is logged). ``~timeout_s`` > 0: when the cell is not ready within it (wall-clock seconds), the node logs
the missing list as an error and exits with :data:`EXIT_NOT_READY`, so that a launch file that starts it
``required`` ends; 0 waits for ever.

Parameters: ``~config`` (config/cell_interfaces.yaml; "" = the package's), ``~roles`` (a list, or names separated by
spaces or commas; default every role of the file), ``~timeout_s`` (0), ``~log_period_s`` (5.0), ``~check_period_s``
(0.5).
"""

__all__ = ["EXIT_NOT_READY", "CellCheckNode", "main"]

import sys
import time

import rosgraph
import rospy
import rosservice
from std_msgs.msg import Bool

from agiprobot_measurement.common.config import non_negative, positive
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, file_param, read_params
from agiprobot_measurement.station.cell_interfaces import (
    MasterSnapshot,
    load_cell_interfaces,
    missing_interfaces,
    parse_roles,
)

#: the exit code when the timeout passes with interfaces still missing (1 is a node that could not start)
EXIT_NOT_READY = 2
#: what a failed question to the master or to a service's provider raises
MASTER_ERRORS = (OSError, rosgraph.MasterException, rosservice.ROSServiceException)


class CellCheckNode:
    def __init__(self):
        self.cell = load_cell_interfaces(file_param("~config"))
        settings = read_params(
            [
                Param("~roles", list(self.cell.roles), parse_roles),
                Param("~timeout_s", 0.0, non_negative),
                Param("~log_period_s", 5.0, positive),
                Param("~check_period_s", 0.5, positive),
            ]
        )
        self.roles = [role.name for role in self.cell.select(settings.roles)]
        self.timeout_s = settings.timeout_s
        self.log_period_s = settings.log_period_s
        self.check_period_s = settings.check_period_s
        self.services = self.cell.wanted(self.roles, "service")
        self.params = self.cell.wanted(self.roles, "param")
        self.master = rosgraph.Master(rospy.get_name())
        self.ready_publisher = rospy.Publisher("~ready", Bool, queue_size=1, latch=True)
        self.ready_publisher.publish(Bool(data=False))
        self.ready = False

    # ------------------------------------------------------------------------------------------ the master
    def snapshot(self) -> MasterSnapshot:
        """What the master reports now (nothing, with a warning, when the master cannot be asked)."""
        try:
            topics = dict(self.master.getPublishedTopics(""))
            offered = {name for name, _providers in self.master.getSystemState()[2]}
            services = {}
            for name in self.services:
                if name in offered:
                    kind = self._service_type(name)
                    if kind is not None:
                        services[name] = kind
            params = frozenset(name for name in self.params if self.master.hasParam(name))
        except MASTER_ERRORS as exc:
            rospy.logwarn_throttle(self.log_period_s, "cell_check: cannot ask the master: %s", exc)
            return MasterSnapshot()
        return MasterSnapshot(topics, services, params)

    @staticmethod
    def _service_type(name):
        """The type of service ``name`` read from its provider, or None when the provider does not answer (a
        registration left behind by a node that died is no service)."""
        try:
            return rosservice.get_service_type(name)
        except MASTER_ERRORS:
            return None

    # ------------------------------------------------------------------------------------------- the loop
    def _set_ready(self, ready: bool) -> None:
        if ready != self.ready:
            self.ready = ready
            self.ready_publisher.publish(Bool(data=ready))

    def run(self) -> int:
        """Check until shutdown; :data:`EXIT_NOT_READY` when the timeout passes first, else 0."""
        started = last_log = time.monotonic()
        timeout = f"{self.timeout_s:g} s" if self.timeout_s > 0 else "no timeout"
        rospy.loginfo("cell_check: waiting for %s (%s)", ", ".join(self.roles), timeout)
        while not rospy.is_shutdown():
            missing = [m.text for m in missing_interfaces(self.cell, self.roles, self.snapshot())]
            now = time.monotonic()
            if not missing:
                if not self.ready:
                    rospy.loginfo("cell_check: cell ready (%s)", ", ".join(self.roles))
                self._set_ready(True)
            elif self.ready:
                self._set_ready(False)
                rospy.logwarn("cell_check: the cell is no longer ready, missing:\n  %s", "\n  ".join(missing))
                last_log = now
            elif self.timeout_s > 0 and now - started >= self.timeout_s:
                rospy.logerr(
                    "cell_check: not ready after %g s, missing (%d):\n  %s",
                    self.timeout_s,
                    len(missing),
                    "\n  ".join(missing),
                )
                return EXIT_NOT_READY
            elif now - last_log >= self.log_period_s:
                rospy.logwarn("cell_check: still missing (%d):\n  %s", len(missing), "\n  ".join(missing))
                last_log = now
            time.sleep(self.check_period_s)
        return 0


def main():
    node = run_node("cell_check", CellCheckNode, spin=False)
    sys.exit(node.run())
