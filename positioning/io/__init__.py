"""Reading ToA datasets: ``toa.csv`` + ``meta.json`` (:mod:`~positioning.io.dataset`), the scale
rule on them before any solve (:mod:`~positioning.io.scale`), and a dataset as the estimators'
problem (:mod:`~positioning.io.prepare`); the project's CSV files as pandas DataFrames
(:mod:`~positioning.io.frames`). Imports only the model.
"""
