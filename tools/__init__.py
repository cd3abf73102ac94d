"""Command-line tools of radar-fusion, one module (or package) per command, and what they share.

Commands (``radar-fusion COMMAND``, table in :mod:`radar_fusion.cli`): ``simulate``
(package :mod:`.simulate`), ``replay``, ``record``, ``evaluate``, ``bench`` (package
:mod:`.bench`), ``demo``, ``clean``, ``outliers`` (:mod:`.outlier_experiment`),
``safety-eval``, ``asterix-in`` / ``asterix-out`` (:mod:`.asterix_bridge`), ``soak``.

Shared: :mod:`.truth` (the truth type, truth.csv reader and writer, interpolation),
:mod:`.gospa` (cut-off assignment, GOSPA), :mod:`.detrend` (robust radar-plane trend),
:mod:`.baseline_stonesoup` (the reference tracker). ``bench_clustering.py`` is a script.
"""
