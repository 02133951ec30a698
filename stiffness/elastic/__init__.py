"""Elastic layer: the one elastic model (:mod:`~stiffness.elastic.model`: a robot with its joint
laws, link bends, preloads, target shift and measurement effects, linear and exact answers at a
pose), the effect library that builds it (:mod:`~stiffness.elastic.effects`), the model file
(:mod:`~stiffness.elastic.model_file`, :func:`~stiffness.elastic.model_file.load_model`) and
the loaded robot's exact equilibrium with link bends (:mod:`~stiffness.elastic.loaded`)."""
