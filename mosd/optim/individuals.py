"""pymoo's populations and individuals built from the swarm's arrays, and back (issue 32).

:class:`~mosd.optim.mopso.MOPSO` keeps its swarm as arrays. pymoo's ``Individual`` and ``Population`` are built
only where pymoo's API needs them: :class:`EvaluatedArrays` builds a generation's individuals when the archive
keeps a candidate or something reads ``algorithm.pop``; ``ask``/``tell`` and other evaluators get Populations of
:func:`new_population`, evaluated by :class:`ArrayEvaluator`, which hands X, F and CV back as arrays.
"""
from __future__ import annotations

import operator

import numpy as np
from pymoo.core.algorithm import Algorithm
from pymoo.core.evaluator import Evaluator
from pymoo.core.individual import Individual, calc_cv
from pymoo.core.population import Population


def restart_pymoo_run(algorithm: Algorithm) -> None:
    """Make pymoo's next ``algorithm.next()`` run the initialisation again (a new run).

    pymoo 0.6 decides between ``_initialize_infill`` and ``_infill`` by the attribute
    ``is_initialized``, set in ``Algorithm.__init__`` and never reset by ``setup``; this is
    the one place that touches it (``tests/test_mopso.py::test_restart_adapter_matches_pymoo``
    fails loudly if a pymoo upgrade renames or stops reading it).
    """
    if not hasattr(algorithm, "is_initialized"):
        raise RuntimeError("pymoo's Algorithm no longer has is_initialized; "
                           "mosd.optim.mopso.restart_pymoo_run needs updating for this pymoo version")
    algorithm.is_initialized = False


#: what :class:`ArrayEvaluator` sets as attributes of the individuals (``Population.set`` does the rest)
_ARRAY_KEYS = ("F", "G", "H")


class SwarmPopulation(Population):
    """pymoo's :class:`~pymoo.core.population.Population` of :func:`new_population`, with what it knows of itself.

    Attributes
    ----------
    fresh : bool
        Nothing in it has been evaluated yet (:class:`ArrayEvaluator` then evaluates every individual without the
        base class's look at each one's ``evaluated`` set); the evaluator clears it.
    rows : tuple (ndarray, list of ndarray) or None
        The array the individuals' X are rows of, and those rows: while every individual still holds its row,
        :func:`population_X` copies the array instead of reading the rows back.
    tags : int or None
        The generation whose ``n_gen``/``n_iter`` tags the individuals carry (:meth:`MOPSO.infill` tags others).

    A slice or a copy is a population of this class with the class defaults below (nothing known), so pymoo's
    own handling of a part of it, or of ``res.history``'s copies, takes the general path.
    """

    fresh: bool = False
    rows: tuple | None = None
    tags: int | None = None


def new_population(X: np.ndarray, generation: int | None = None) -> SwarmPopulation:
    """``Population.new("X", X)``: one fresh :class:`~pymoo.core.individual.Individual` per row, built directly.

    The individuals are built by pymoo's constructor, X set (its public property) to the row of a copy of X
    owned by this population (``Population.set`` copies each row, so that no individual holds a view of a
    caller's array, pymoo #455); what is skipped is the generic path: a new configuration dictionary per
    individual (one shared, never modified, as pymoo only reads it) and ``Individual.set``'s attribute lookup
    per key and individual (issue 32). With ``generation``, each individual's data carry pymoo's ``n_gen`` and
    ``n_iter`` tags (what ``Algorithm.infill`` sets afterwards, one individual at a time).
    """
    config = Individual.default_config()
    owned = np.array(X, dtype=float)
    rows = list(owned)
    built = []
    for row in rows:
        individual = Individual(config=config)
        individual.X = row
        if generation is not None:
            individual.data["n_gen"] = individual.data["n_iter"] = generation
        built.append(individual)
    population = _object_array(built).view(SwarmPopulation)
    # read by ArrayEvaluator.eval: nothing here is evaluated yet, and the rows of ``owned`` are the individuals' X
    # as long as each individual still holds its row (MOPSO.infill: and the tags are set)
    population.fresh, population.rows, population.tags = True, (owned, rows), generation
    return population


def _object_array(items: list) -> np.ndarray:
    """``items`` as a 1-d object array (``np.array`` would look into the individuals for a shape)."""
    array = np.empty(len(items), dtype=object)
    array[:] = items
    return array


def constraint_violation(out: dict, n: int, config: dict) -> np.ndarray:
    """CV (n, 1) of a problem's output, as ``Individual.CV`` computes it for each row.

    pymoo's ``calc_cv`` on the whole G and H arrays loops over the rows with the function ``Individual.CV``
    calls; a problem with constraints but none set gives a scalar, broadcast to every row.
    """
    return np.array(np.broadcast_to(calc_cv(G=out.get("G"), H=out.get("H"), config=config), (n,)),
                    dtype=float).reshape(-1, 1)


def population_X(pop: Population) -> np.ndarray:
    """The individuals' X as one new array: a copy of :func:`new_population`'s array while every individual still
    holds its row of it (nothing replaced an X since), else read from the individuals."""
    owned, rows = pop.rows if isinstance(pop, SwarmPopulation) and pop.rows is not None else (None, None)
    if rows is not None and len(rows) == len(pop) and all(map(operator.is_, [ind.X for ind in pop], rows)):
        return owned.copy()
    return np.array([individual.X for individual in pop])


class ArrayEvaluator(Evaluator):
    """pymoo's :class:`~pymoo.core.evaluator.Evaluator` that sets the results on the individuals directly.

    The same problem call and the same attributes as the base class (F, G, H as rows of a copy of
    the problem's output, ``evaluated``, CV where the problem has constraints, computed by pymoo's
    ``calc_cv`` row by row as ``Individual.CV`` would), without ``Population.get``/``set``'s
    generic per-key, per-individual lookups; the evaluated arrays are kept in
    :attr:`last` (population, X, F, CV) so that :class:`MOPSO` does not read them back.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.last: tuple | None = None
        self._arrays: tuple | None = None

    def eval(self, problem, pop, skip_already_evaluated=None, evaluate_values_of=None, count_evals=True, **kwargs):
        self.last = self._arrays = None
        if isinstance(pop, SwarmPopulation) and pop.fresh and len(pop):
            # :func:`new_population`'s individuals have nothing evaluated: the base class's check of every
            # individual's ``evaluated`` set would select them all
            values = self.evaluate_values_of if evaluate_values_of is None else evaluate_values_of
            self._eval(problem, pop, values, **kwargs)
            if count_evals:
                self.n_eval += len(pop)
            if self.callback:
                self.callback(pop)
            pop.fresh = False
        else:
            pop = super().eval(problem, pop, skip_already_evaluated, evaluate_values_of, count_evals, **kwargs)
        # the arrays describe ``pop`` when every individual was evaluated now (the base class passes pop[I])
        if self._arrays is not None and isinstance(pop, Population) and len(self._arrays[0]) == len(pop):
            self.last = (pop, *self._arrays[1:])
        self._arrays = None
        return pop

    def _eval(self, problem, pop, evaluate_values_of, **kwargs):
        X = population_X(pop)
        out = problem.evaluate(X, return_values_of=evaluate_values_of, return_as_dictionary=True, **kwargs)
        keys = set(out.keys())
        # one copy per key (the problem may reuse its output buffers); each individual gets a row of it, the
        # memory Population.set's copy of every row (pymoo #455) protects being this population's own
        owned = {key: np.array(value, copy=True) for key, value in out.items() if value is not None}
        names = [key for key in owned if key in _ARRAY_KEYS]
        columns = [list(owned[key]) for key in owned if key in _ARRAY_KEYS]
        others = {key: value for key, value in owned.items() if key not in _ARRAY_KEYS}
        CV = None
        if problem.has_constraints() and len(pop):
            CV = constraint_violation(out, len(pop), pop[0].config)
            names.append("CV")
            columns.append(list(CV))
        for individual, *rows in zip(pop, *columns):
            # pymoo's public properties F, G, H and CV
            for name, row in zip(names, rows):
                setattr(individual, name, row)
            individual.evaluated.update(keys)
        if others:
            pop.set(**others)
        self._arrays = (pop, X, owned["F"], CV if CV is not None else np.zeros((len(pop), 1)))


class EvaluatedArrays:
    """One generation's evaluated candidates as arrays, whose pymoo individuals are built when something asks.

    What :meth:`MOPSO.next` hands to ``advance`` instead of a Population: the swarm reads the arrays,
    :meth:`GridArchive.update` asks for the individuals of the candidates it keeps (:meth:`select`), and
    ``algorithm.pop``/``off`` (``res.pop``, ``res.history``, callbacks) for all of them (:meth:`population`).
    Each individual is built once, on first request, exactly as :func:`new_population` and
    :class:`ArrayEvaluator` build it (X a row of a copy taken before the evaluation, F/G/H rows of copies of the
    problem's output, CV where the problem has constraints, ``evaluated``, the ``n_gen``/``n_iter`` tags), so
    the archive's members and ``pop`` share the same objects as before. Building and freeing a hundred
    individuals a generation that nothing reads was the largest part of the optimiser's own time (issue 32).
    """

    def __init__(self, X: np.ndarray, out: dict, CV: np.ndarray | None, generation: int, config: dict,
                 evaluated_X: np.ndarray | None = None):
        self.X = X
        self.keys = set(out.keys())
        self.outputs = {key: np.array(value, copy=True) for key, value in out.items() if value is not None}
        self.CV = CV
        #: X (the array the problem evaluated), F, CV (n, 1; zeros without constraints): what the swarm reads
        self.swarm = (X if evaluated_X is None else evaluated_X, self.outputs.get("F"),
                      CV if CV is not None else np.zeros((len(X), 1)))
        self.generation = generation
        self.config = config
        self.individuals = np.full(len(X), None, dtype=object)
        self._population: Population | None = None

    def __len__(self) -> int:
        return len(self.X)

    def select(self, index: np.ndarray) -> Population:
        """The individuals of rows ``index`` (int array), built where not yet."""
        chosen = self.individuals[index]
        missing = index[np.equal(chosen, None)]
        if len(missing):
            self._build(missing.tolist())
            chosen = self.individuals[index]
        return chosen.view(Population)

    def population(self) -> Population:
        """All the individuals, in row order (the same Population object on every call)."""
        if self._population is None:
            self._population = self.select(np.arange(len(self.X)))
        return self._population

    def _build(self, rows: list[int]) -> None:
        columns = [(key, value) for key, value in self.outputs.items() if key in _ARRAY_KEYS]
        if self.CV is not None:
            columns.append(("CV", self.CV))
        X, keys, tag, config = self.X, self.keys, self.generation, self.config
        built = []
        for i in rows:
            # pymoo's constructor and public properties (X, F, G, H, CV, evaluated, data)
            individual = Individual(config=config)
            individual.X = X[i]
            individual.evaluated.update(keys)
            individual.data["n_gen"] = individual.data["n_iter"] = tag
            for name, values in columns:
                setattr(individual, name, values[i])
            built.append(individual)
        others = {key: value for key, value in self.outputs.items() if key not in _ARRAY_KEYS}
        for key, values in others.items():
            for i, individual in zip(rows, built):
                # Population.set's copy of a view (pymoo #455)
                value = values[i]
                individual.set(key, value.copy() if isinstance(value, np.ndarray) and not value.flags["OWNDATA"]
                               else value)
        self.individuals[rows] = _object_array(built)
