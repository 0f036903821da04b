"""View-selection policies of the 3D loop over a narrow :class:`~.base.PolicyContext`, chosen by name.

Public face: :func:`.registry.make_policy` and :data:`.registry.POLICIES`, :class:`.base.PolicyContext`,
:class:`.base.Policy`, :class:`.base.ViewChoice`, :func:`.base.motion_time_s`, :func:`.base.weighted_score`.

Modules:

- :mod:`.base` the context, the shared pool and ranking, the motion-time estimate;
- :mod:`.ours` ours: a weighted sum of PhoXi-aware gains discounted by the motion;
- :mod:`.touring` ours_tour: ours' opening, then a receding-horizon tour over the predicted surface;
- :mod:`.metrics` one volumetric metric with rpg's utility;
- :mod:`.baselines` random, fixed hemisphere, the report's strategy in 3D;
- :mod:`.registry` the policies by method name.
"""
