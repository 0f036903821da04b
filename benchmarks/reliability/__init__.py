"""The reliability probe, replayed: hostile inputs to every command-line tool, each run judged ``holds`` or ``DEFECT``.

    python -m benchmarks.reliability                      # every probe of conditions/reliability.yaml
    python -m benchmarks.reliability --only P4 C9 K8 --json fuzz.json --timeout 60
    python -m benchmarks.reliability --list               # the probes, without running them

``inputs`` builds the hostile inputs (fixed seeds) into a temporary folder; ``probes`` is the catalogue (the probe's
row ids, e.g. P4 = plan_measurement.py on random bytes); ``judge`` runs each child under a time and memory watch and
judges how it ended; ``nodes`` replays probes against the ROS nodes on a private master; ``run`` is the command.
"""
