"""The planning pipeline's stages and one overall progress figure from a stage's own progress.

The TrajectoryManager reports ``(stage, fraction of the stage done 0..1, message)``; the node turns that into
the PlanMeasurement feedback's overall progress and the command line into one bar per stage.
"""

from __future__ import annotations

__all__ = ["STAGES", "STAGE_WEIGHTS", "overall_progress"]

#: the stages in the order they first run (set cover and mechanics alternate in rounds)
STAGES = ("sampling", "metrology", "mechanics", "set cover", "connection")

#: typical share of each stage in the planning time, for one overall progress figure (sums to 1)
STAGE_WEIGHTS = {"sampling": 0.05, "metrology": 0.25, "mechanics": 0.15, "set cover": 0.35, "connection": 0.2}


def overall_progress(stage: str, fraction: float) -> float:
    """Share (0..1) of the whole planning run done when ``stage`` is ``fraction`` done; an unknown stage counts
    as the first one with nothing done."""
    index = STAGES.index(stage) if stage in STAGES else 0
    done = sum(STAGE_WEIGHTS[s] for s in STAGES[:index]) + STAGE_WEIGHTS.get(stage, 0.0) * fraction
    return min(done, 1.0)
