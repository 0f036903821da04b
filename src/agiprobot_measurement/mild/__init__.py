"""Robot model services of the MILD mobile robot with pan-tilt unit, and its occupancy map."""
