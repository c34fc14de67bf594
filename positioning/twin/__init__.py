"""The subpackage ``positioning.twin`` holds the estimator that positions against a ray-traced
fingerprint map and everything it needs: the map file (:mod:`~positioning.twin.fingerprint`), the
noiseless first-lobe receiver (:mod:`~positioning.twin.lobe`), the map as a lattice with its
cache and rasters (:mod:`~positioning.twin.lattice`), the match to cells
(:mod:`~positioning.twin.match`), the re-synthesis of paths (:mod:`~positioning.twin.resynth`) and
the estimator (:mod:`~positioning.twin.estimator`). It imports the models and estimators below it,
nothing above.
"""
