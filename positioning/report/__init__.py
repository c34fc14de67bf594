"""The subpackage ``positioning.report`` writes what people and tools read: every method run on a
dataset (:mod:`~positioning.report.runs`), Table II and the integrity table
(:mod:`~positioning.report.tables`), the figures (:mod:`~positioning.report.figures`), the
report directory (:mod:`~positioning.report.write`, through :mod:`~positioning.report.files`) and
a method's ``fixes.csv`` (:mod:`~positioning.report.fixes_file`).
"""
