"""Parameter declaration and validation shared by every component.

Every component validates its ``__init__`` arguments with these helpers so that a
bad value fails at construction time with one line naming the parameter and the
allowed range (the app turns :class:`ConfigError` into exit code 2).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
import math
import re
import textwrap
from typing import Any, ClassVar, Iterable

import numpy as np


class ConfigError(ValueError):
    """A component parameter or configuration key has an invalid value."""


@dataclass(frozen=True)
class Interval:
    """A real interval; ``open_low``/``open_high`` exclude the bound.

    ``integer=True`` declares an integer parameter (e.g. the length of a
    persistence rule): optimisers round it with :meth:`round`, :func:`check_in`
    refuses non-integral values.
    """

    low: float
    high: float
    open_low: bool = False
    open_high: bool = False
    integer: bool = False

    def __contains__(self, value: float) -> bool:
        v = float(value)
        if math.isnan(v):
            return False
        lo_ok = v > self.low if self.open_low else v >= self.low
        hi_ok = v < self.high if self.open_high else v <= self.high
        return lo_ok and hi_ok

    def round(self, value, clip: bool = False):
        """``value`` rounded to the nearest integer when the interval is integer (else unchanged).

        The one rounding of integer parameters (the tuning problem, the
        optimisers, ``with_params``, the detectors' populations, the compiled
        chart and the preflight all call it). Ties go to the even integer, as
        :func:`numpy.round` and Python's ``round`` do.

        Parameters
        ----------
        value : float or ndarray
        clip : bool
            Also move the result to the nearest integer inside the interval
            (an open bound excludes its own value). ``low`` and ``high`` may then
            be arrays broadcasting against ``value`` (one box per column).

        Returns
        -------
        int (a finite scalar), float (NaN, ±inf) or ndarray of float
        """
        if not self.integer:
            return value
        rounded = np.round(value)
        if clip:
            low = np.floor(self.low) + 1.0 if self.open_low else np.ceil(self.low)
            high = np.ceil(self.high) - 1.0 if self.open_high else np.floor(self.high)
            rounded = np.clip(rounded, low, high)
        if np.ndim(rounded) == 0:  # a scalar as the user would write it, for the error messages
            rounded = float(rounded)
            return int(rounded) if math.isfinite(rounded) else rounded
        return rounded

    def __str__(self) -> str:
        text = f"{'(' if self.open_low else '['}{self.low:g}, {self.high:g}{')' if self.open_high else ']'}"
        return f"integers in {text}" if self.integer else text


def check_in(name: str, value: Any, interval: Interval) -> float:
    """Return ``float(value)`` or raise ConfigError naming ``name`` and ``interval``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}={value!r} is not a number; allowed: {interval}") from None
    if v not in interval:
        raise ConfigError(f"{name}={value!r} is out of range; allowed: {interval}")
    if interval.integer:
        if not v.is_integer():
            raise ConfigError(f"{name}={value!r} is not an integer; allowed: {interval}")
        return int(v)
    return v


def check_int(name: str, value: Any, low: int, high: float = math.inf) -> int:
    """Return ``int(value)`` or raise ConfigError when not an integer in [low, high]."""
    upper = "inf" if high == math.inf else str(int(high))
    integral = not isinstance(value, bool) and _is_number(value) and float(value).is_integer()
    if not integral:
        raise ConfigError(f"{name}={value!r} is not an integer; allowed: integers in [{low}, {upper}]")
    v = int(value)
    if not low <= v <= high:
        raise ConfigError(f"{name}={value!r} is out of range; allowed: integers in [{low}, {upper}]")
    return v


def check_choice(name: str, value: Any, choices: Iterable[Any]) -> Any:
    """Return ``value`` if it is one of ``choices`` else raise ConfigError listing them."""
    choices = tuple(choices)
    if value not in choices:
        allowed = ", ".join(str(c) for c in choices)
        raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
    return value


def check_names(name: str, value: Any, allowed: str) -> tuple[str, ...]:
    """A name or a non-empty list of names, as a tuple of str; ``allowed`` says what they may be."""
    names = (value,) if isinstance(value, str) else tuple(str(v) for v in value)
    if not names:
        raise ConfigError(f"{name}=[] is empty; allowed: {allowed}")
    return names


def check_matrix(name: str, value: Any, shape: tuple[int, int], psd: bool = True) -> np.ndarray:
    """A covariance-like matrix: a scalar, a diagonal (1-D) or a full matrix of ``shape``."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.eye(shape[0]) * float(arr)
    elif arr.ndim == 1:
        if arr.shape[0] != shape[0]:
            raise ConfigError(f"{name} has {arr.shape[0]} diagonal entries; allowed: {shape[0]}")
        arr = np.diag(arr)
    if arr.shape != shape:
        raise ConfigError(f"{name} has shape {arr.shape}; allowed: {shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} has non-finite entries; allowed: finite numbers")
    if psd:
        if not np.allclose(arr, arr.T):
            raise ConfigError(f"{name} is not symmetric; allowed: symmetric positive semi-definite")
        if np.linalg.eigvalsh(arr).min() < -1e-12 * max(1.0, np.abs(arr).max()):
            raise ConfigError(f"{name} is not positive semi-definite; allowed: symmetric positive semi-definite")
    return arr


def _is_number(value: Any) -> bool:
    try:
        float(value)
    except (TypeError, ValueError):
        return False
    return True


# -- parameters declared once ----------------------------------------------------------------
@dataclass(frozen=True)
class Param:
    """One parameter of a component, declared once: its domain, its meaning, whether it is tuned.

    A component lists its parameters in the class attribute ``params`` (name ->
    ``Param``) and gets from that one declaration the validation in ``__init__``
    (:meth:`Component._assign`), ``get_params``, ``with_params``, ``clone`` and the
    "Parameters" section of its docstring; the config key of a parameter is
    ``<config_group>.<name>`` (e.g. ``detector.persistence``).

    Parameters
    ----------
    domain : Interval, tuple, callable or None
        * an :class:`Interval` (``integer=True``: an integer parameter); either bound
          may be the name of a parameter declared before this one, whose value on
          the component is the bound (e.g. ``Interval(0.0, "threshold_max")``);
        * a tuple: the allowed values;
        * a callable ``(key, value, component) -> value`` that validates (raising
          :class:`ConfigError`) and returns the stored value (matrices, sub-components);
        * None: any value.
    doc : str
        What the parameter means (one sentence; the range is added from ``domain``).
    tunable : bool
        An optimiser may tune it (a detector's search space: ``Detector.tunable``).
    optional : bool
        None is also allowed (the meaning of None goes in ``doc``).
    sequence : bool
        A sequence of values, each in ``domain``; stored as a tuple.
    nonzero : bool
        0 is refused (a fault of amplitude 0 would be no fault).
    kind : str
        The type shown in the docstring where ``domain`` does not tell it (a callable).
    """

    domain: Any
    doc: str
    tunable: bool = False
    optional: bool = False
    sequence: bool = False
    nonzero: bool = False
    kind: str = ""

    def interval(self, owner: Any) -> Interval:
        """The Interval domain with bounds that name other parameters replaced by their values on ``owner``."""
        d = self.domain
        if isinstance(d.low, str) or isinstance(d.high, str):
            low = getattr(owner, d.low) if isinstance(d.low, str) else d.low
            high = getattr(owner, d.high) if isinstance(d.high, str) else d.high
            return Interval(low, high, d.open_low, d.open_high, d.integer)
        return d

    def check(self, key: str, value: Any, owner: Any) -> Any:
        """The validated value to store, or ConfigError naming ``key`` and the allowed values."""
        if value is None and self.optional:
            return None
        if self.sequence:
            if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
                raise ConfigError(f"{key}={value!r} is not a list; allowed: a list of {self._domain_text()}")
            return tuple(self._check_one(key, v, owner) for v in value)
        return self._check_one(key, value, owner)

    def _check_one(self, key: str, value: Any, owner: Any) -> Any:
        d = self.domain
        if isinstance(d, Interval):
            interval = self.interval(owner)
            if interval.integer and not (interval.open_low or interval.open_high):
                checked = check_int(key, value, interval.low, interval.high)
            else:
                checked = check_in(key, value, interval)
            if self.nonzero and checked == 0:
                raise ConfigError(f"{key}={value!r} is not allowed; allowed: a non-zero number in {interval}")
            return checked
        if isinstance(d, tuple):
            return check_choice(key, value, d)
        if callable(d):
            return d(key, value, owner)
        return value

    def _domain_text(self) -> str:
        d = self.domain
        if isinstance(d, Interval):
            low, high = (v if isinstance(v, str) else f"{v:g}" for v in (d.low, d.high))
            text = f"{'(' if d.open_low else '['}{low}, {high}{')' if d.open_high else ']'}"
            return f"int in {text}" if d.integer else f"float in {text}"
        if isinstance(d, tuple):
            return "{" + ", ".join(repr(c) for c in d) + "}"
        return self.kind or "object"

    def describe(self, name: str) -> str:
        """The docstring entry: ``name : type and range[, optional][, tunable]`` and the doc."""
        kind = self._domain_text()
        if self.sequence:
            kind = f"sequence of {kind}"
        flags = "".join([", non-zero" if self.nonzero else "", ", optional" if self.optional else "",
                         ", tunable" if self.tunable else ""])
        return f"{name} : {kind}{flags}\n" + textwrap.fill(self.doc, 96, initial_indent="    ",
                                                           subsequent_indent="    ")


class _TunableView:
    """``Component.tunable``: name -> Interval of the tunable parameters (bounds resolved on an instance)."""

    def __get__(self, owner: Any, cls: type) -> dict[str, Interval]:
        return {name: (p.domain if owner is None else p.interval(owner))
                for name, p in cls.params.items() if p.tunable}


class Component:
    """Base of every component: parameters declared once in ``params`` (see :class:`Param`).

    Subclasses set ``config_group`` (the config group whose keys they read, e.g.
    ``"detector"``) and ``params``; a subclass's ``params`` extend its parent's
    (a name mapped to None removes an inherited one). ``__init__`` keeps its
    explicit signature (the config keys) and starts with ``self._assign(locals())``.
    """

    config_group: ClassVar[str] = "component"
    params: ClassVar[dict[str, Param]] = {}
    #: name -> Interval of the parameters an optimiser may tune, in declaration order
    tunable = _TunableView()

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        inherited: dict[str, Param] = {}
        for base in reversed(cls.__mro__[1:]):
            inherited.update(getattr(base, "params", {}) or {})
        own = cls.__dict__.get("params", {})
        merged = {**inherited, **own}
        cls.params = {name: p for name, p in merged.items() if p is not None}
        doc = cls.__dict__.get("__doc__")
        if doc and cls.params and not re.search(r"^\s*Parameters\n\s*-{10}", doc, re.M):
            cls.__doc__ = _with_parameters_section(cls.__doc__, cls.params)

    @classmethod
    def _key(cls, name: str) -> str:
        return f"{cls.config_group}.{name}"

    def _assign(self, values: dict) -> None:
        """Validate and store every declared parameter found in ``values`` (``__init__``'s ``locals()``).

        In declaration order, so that a bound naming an earlier parameter sees its value.
        """
        for name, param in self.params.items():
            if name in values:
                setattr(self, name, param.check(self._key(name), values[name], self))

    def get_params(self) -> dict[str, Any]:
        """The declared parameters and their values (what ``__init__`` accepts back)."""
        return {name: getattr(self, name) for name in self.params}

    def with_params(self, **changes) -> "Component":
        """A new, validated component with some parameters replaced; fitted state is not carried over.

        Integer parameters are rounded first (:meth:`Interval.round`): an
        optimiser's real-valued coordinates give integral designs.
        """
        unknown = sorted(set(changes) - set(self.params))
        if unknown:
            raise ConfigError(f"{self.config_group} parameter {unknown[0]!r} is unknown; "
                              f"allowed: {', '.join(self.params)}")
        for name, value in changes.items():
            domain = self.params[name].domain
            if isinstance(domain, Interval) and domain.integer and _is_number(value) and not isinstance(value, bool):
                changes[name] = domain.round(float(value))
        return type(self)(**{**self.get_params(), **changes})

    def clone(self) -> "Component":
        """An unfitted copy with the same parameters (sub-components cloned too, other values copied)."""
        return type(self)(**{name: _clone(value) for name, value in self.get_params().items()})


def _clone(value: Any) -> Any:
    if isinstance(value, Component):
        return value.clone()
    if isinstance(value, (list, tuple)):
        return type(value)(_clone(v) for v in value)
    return copy.deepcopy(value)


def _with_parameters_section(doc: str, params: dict[str, Param]) -> str:
    """``doc`` with a NumPy "Parameters" section generated from the declaration appended."""
    lines = doc.expandtabs().splitlines()
    indents = [len(line) - len(line.lstrip()) for line in lines[1:] if line.strip()]
    pad = " " * (min(indents) if indents else 0)
    body = "\n".join(pad + row if row else row
                     for p in params for row in params[p].describe(p).splitlines())
    section = f"{pad}Parameters\n{pad}----------\n{body}\n"
    # NumPy order: Parameters before any later section (Notes, Examples, ...)
    later = re.search(r"^[ \t]*(Returns|Raises|See Also|Notes|References|Examples)\n[ \t]*-{3,}", doc, re.M)
    if later:
        return f"{doc[:later.start()]}{section}\n{doc[later.start():]}"
    return f"{doc.rstrip()}\n\n{section}{pad}"
