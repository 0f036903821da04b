#!/usr/bin/env python3
"""Upstream's node type SetFocusPoint.py: agiprobot_measurement's set_focus_point on the MILD."""

from agiprobot_measurement.ros.nodes.set_focus_point import main

if __name__ == "__main__":
    main()
