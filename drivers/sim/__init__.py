"""The virtual rig: a physically faithful simulation of target, light, optics, sensor, stage,
grating and timing (issue 3).

Entry points (stable API):

* :func:`graytrack.drivers.sim.scenarios.build_rig` ``(scenario, effects=(), seed=0) -> VirtualRig``,
  ``list_scenarios()``, ``list_effects()``;
* :class:`graytrack.drivers.sim.rig.VirtualRig` — ``record(seconds, trajectory) -> (Recording, Truth)``,
  ``render(x_mm_samples, t_s) -> frames (K, R, n)``, ``make_stage()``, ``make_grating(stage)``;
* :class:`graytrack.drivers.sim.stage.SimStage` — a servo axis with ``move_to``/``stop``/
  ``position``/``velocity``/``on_target``; :class:`graytrack.drivers.sim.grating.GratingReadout`.

One module per physical part: target.py, illumination.py, optics.py, sensor.py, stage.py,
grating.py, timing.py; effects.py is the registry of named imperfections, scenarios.py the named
rigs, rig.py puts them together. ``paper.py`` is the seed paper's Table 2 field.
"""
