"""The positioning methods by name: the registry of methods and their parameters
(:mod:`~positioning.methods.registry`) and running one on a problem, bounded to the service area
with the integrity figures (:mod:`~positioning.methods.run`, where :func:`positioning.locate`
lives). Imports the model, the estimators, the twin and the evaluation.
"""
