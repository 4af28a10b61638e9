"""The tested controller and estimator as portable C (``twin export``), run back in the twin's loop
(software in the loop: the ``export:DIR`` kinds) and on an emulated microcontroller (processor in
the loop).

* :mod:`twin.export.literals`: exact C literals of the design's numbers, float64 or float32;
* :mod:`twin.export.control`, :mod:`twin.export.baselines`, :mod:`twin.export.ekf`: the emitters
  of the controllers and the drive, of the baseline estimators, of the EKF;
* :mod:`twin.export.generate`: the export directory's files and manifest;
* :mod:`twin.export.sil`: an export compiled with the host's compiler, as a controller and an
  estimator of the twin (the ``export:DIR`` kinds of :mod:`twin.registry`);
* :mod:`twin.export.pil`: an export cross-compiled for a Cortex-M4F and run under QEMU.

The C files that are not generated are in ``twin/export/c/``.
"""
