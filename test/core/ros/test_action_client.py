"""The action client keeps a goal's transitions that arrive before send_goal has stored its handle."""

from actionlib import CommState, SimpleActionClient, SimpleGoalState

from agiprobot_measurement.ros.action_client import ActionClient


class _Handle:
    def __init__(self, state):
        self.state = state

    def get_comm_state(self):
        return self.state

    def get_goal_status(self):
        return 4  # GoalStatus.ABORTED

    def get_result(self):
        return None


class _FastServer:
    """Answers within send_goal, as a server on another thread can: ACTIVE, then at once DONE (a refused goal)."""

    ns = "/scaled_pos_joint_traj_controller/follow_joint_trajectory"

    def __init__(self, final_state):
        self.final_state = final_state
        self.handles = []

    def send_goal(self, goal, transition_cb, feedback_cb):
        handle = _Handle(CommState.ACTIVE)
        self.handles.append(handle)
        transition_cb(handle)
        handle.state = self.final_state
        transition_cb(handle)
        return handle


def _client(cls, server):
    import threading

    client = cls.__new__(cls)  # no ROS master: the state machine only
    if cls is ActionClient:
        client._early_lock, client._sending, client._early = threading.RLock(), False, []
    client.action_client = server
    client.simple_state = SimpleGoalState.DONE
    client.gh = None
    client.done_condition = threading.Condition()
    return client


def test_early_done_is_not_lost(monkeypatch):
    errors = []
    monkeypatch.setattr("rospy.logerr", lambda *a, **k: errors.append(a))
    done = []
    plain = _client(SimpleActionClient, _FastServer(CommState.DONE))
    plain.send_goal(object(), done_cb=lambda *a: done.append("plain"))
    assert plain.simple_state == SimpleGoalState.PENDING  # actionlib's own client: lost, would wait forever
    assert errors and not done
    errors.clear()
    client = _client(ActionClient, _FastServer(CommState.DONE))
    client.send_goal(object(), done_cb=lambda status, result: done.append("ours"))
    assert client.simple_state == SimpleGoalState.DONE
    assert done == ["ours"] and errors == []


def test_early_active_is_replayed_and_old_handles_are_ignored(monkeypatch):
    errors = []
    monkeypatch.setattr("rospy.logerr", lambda *a, **k: errors.append(a))
    server = _FastServer(CommState.ACTIVE)
    client = _client(ActionClient, server)
    client.send_goal(object())
    assert client.simple_state == SimpleGoalState.ACTIVE
    first = server.handles[0]
    client.send_goal(object())  # a new goal; the first one's late news must not disturb it
    first.state = CommState.DONE
    client._handle_transition(first)
    assert client.simple_state == SimpleGoalState.ACTIVE
    assert errors == []
