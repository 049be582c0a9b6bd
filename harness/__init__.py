"""What the tests and the benchmarks share, kept out of the installed package.

``setup.py`` does not install this folder: the robot gets neither the camera feed that drives
the node over DDS (:mod:`.feed`), nor the photometric perturbations (:mod:`.perturbations`),
the render benchmark's scene (:mod:`.scene`) or the Cycles silhouette check
(:mod:`.silhouettes`). Import it with the repository root on the path (pytest's
``pythonpath``, or ``python -m`` from the root).
"""
