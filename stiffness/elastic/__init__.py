"""Elastic layer: the one elastic model (:mod:`~stiffness.elastic.model`: a robot with its joint
laws, link bends, preloads, target shift and measurement effects; its linear and exact answers at
a pose, :mod:`~stiffness.elastic.state`), the effect library that builds it
(:mod:`~stiffness.elastic.effects`), the model file (what it holds,
:mod:`~stiffness.elastic.model_contents`; its reader and
:func:`~stiffness.elastic.model_file.load_model`, :mod:`~stiffness.elastic.model_file`; the
elastic model it makes, :mod:`~stiffness.elastic.file_model`) and the loaded robot's exact
equilibrium with link bends (:mod:`~stiffness.elastic.loaded`)."""
