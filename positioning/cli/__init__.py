"""The subpackage ``positioning.cli`` holds the commands ``estimate-positions``
(:mod:`~positioning.cli.estimate`) and ``accuracy-report`` (:mod:`~positioning.cli.accuracy`) and
what they share (:mod:`~positioning.cli.options`): argument parsing and printing only.
"""
