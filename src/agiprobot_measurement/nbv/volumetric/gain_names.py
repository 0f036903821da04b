"""The names of the view gains of :mod:`.gains`, in a module of their own so that validating a request
(:mod:`.reconstruction`, the ROS node) does not import numba."""

GAIN_NAMES = (
    "occlusion_aware",
    "unobserved_voxel",
    "rear_side_voxel",
    "rear_side_entropy",
    "proximity_count",
    "average_entropy",
    "area_factor",
    "report",
)
