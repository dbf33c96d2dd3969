"""The papers' systems as reusable computations behind their reports (tables, figures, Monte Carlo studies).

One module per paper; each composes components of the other packages and returns
plain numbers and arrays. A module may also offer a *study*: a class with its
parameters in ``__init__`` and one verb,

    run(experiment, result, out_dir) -> (metrics: dict[str, float], files: list[Path])

which the app calls after the experiment when the config's ``study`` key names it
(the ``+experiment=paper00N`` presets do): the metrics land in ``summary.json``
(under ``"study"``) and in MLflow, the files (figures, CSVs) in the run directory
and as MLflow artifacts. ``experiment`` is the :class:`mosd.experiment.Experiment`
that ran (its seed, budgets and components), ``result`` its
:class:`~mosd.experiment.ExperimentResult` (the tuned detector). A study draws its
Monte Carlo runs from the experiment's seed streams, so nothing it reports was
seen by the optimiser.
"""


def run_designs(study, experiment, designs: dict, out_dir):
    """What a report command does with its designs: the study's data, metrics and figures (in ``out_dir``)."""
    from pathlib import Path

    data = study.compute(experiment, designs)
    return data, study.metrics(data), study.write_figures(data, Path(out_dir))
