"""An actionlib SimpleActionClient without the race of its Python implementation.

``SimpleActionClient.send_goal`` stores the new goal handle only after the goal has been published. A fast server
(``robot_sim`` accepts a goal within a millisecond) can answer before that: the client then sees a transition of
a handle it does not track yet, logs "Got a transition callback on a goal handle that we're not tracking" as an
error and drops it. A dropped ACTIVE is harmless, a dropped DONE (a goal refused at once) leaves
``wait_for_result`` waiting forever. This client keeps such early transitions and replays the newest state of the
new handle once it is stored; transitions of handles it no longer tracks (earlier goals) are ignored quietly.
"""

from __future__ import annotations

import threading

from actionlib import SimpleActionClient, SimpleGoalState

__all__ = [
    "ActionClient",
]


class ActionClient(SimpleActionClient):
    """Drop-in replacement of ``actionlib.SimpleActionClient`` (same constructor and methods)."""

    def __init__(self, ns, ActionSpec):
        self._early_lock = threading.RLock()  # also serialises the handler: a replay never races a live callback
        self._sending = False
        self._early = []
        super().__init__(ns, ActionSpec)

    def send_goal(self, goal, done_cb=None, active_cb=None, feedback_cb=None):
        with self._early_lock:
            self._sending, self._early = True, []
        try:
            super().send_goal(goal, done_cb, active_cb, feedback_cb)
        finally:
            with self._early_lock:
                self._sending, early = False, self._early
                self._early = []
        with self._early_lock:
            if self.gh is not None and self.simple_state != SimpleGoalState.DONE and any(h == self.gh for h in early):
                # the handler reads the handle's current state: one call catches up with everything it missed
                SimpleActionClient._handle_transition(self, self.gh)

    def _handle_transition(self, gh):
        with self._early_lock:
            if gh != self.gh:
                if self._sending:
                    self._early.append(gh)
                return
            SimpleActionClient._handle_transition(self, gh)
