"""Measurement planning: part loading, viewpoints, set cover, ordering, execution plans, the TrajectoryManager."""
