"""The papers' systems as reusable studies behind their reports (tables, figures, Monte Carlo studies).

One module (or package) per system, each with a :class:`~mosd.systems.base.Study`
subclass that composes components of the other packages and returns plain
numbers and arrays; its contract (``compute``, ``metrics``, ``write_figures``,
``run``) is documented in :mod:`mosd.systems.base`. The app calls
``run(experiment, result, out_dir) -> (metrics, files)`` after the experiment
when the config's ``study`` key names a study (the ``+experiment=paperNNN``
presets do): the metrics land in ``summary.json`` (under ``"study"``) and in
MLflow, the files (figures, CSVs) in the run directory and as MLflow
artifacts. A study draws its Monte Carlo runs from the experiment's seed
streams, so nothing it reports was seen by the optimiser.

Each system also has a report command (``python -m mosd.systems.paperNNN``,
built with :mod:`mosd.systems.cli`) that runs the study on the preset's
experiment (``conf/experiment/paperNNN.yaml``) with the design recorded in
``mosd/systems/designs/paperNNN.json``, without the optimiser.
"""
