"""Methods asked for as text, as ``evfuse fill``, ``run``, ``bench`` and ``reproduce`` take them:
labels and ``[METHOD.]KEY=VALUE`` settings into checked :class:`fusion.methods.MethodVariant`
(:func:`method_variants`), and the one method of a fill with the paper's stage parameters into
the :class:`fusion.methods.ResolvedMethod` the fill runs (:func:`fill_request`).

Refusals are :class:`sim.validation.ParameterError`: they name the parameters ``method``,
``param`` and the stage parameters (``threshold``, ``sigma``...) as placeholders, which the
command line names by its flags (``--method``, ``--param``, ``--threshold``...).
"""

from __future__ import annotations

from collections.abc import Sequence

from fusion.fill.records import DenseParams
from fusion.methods._errors import MethodError
from fusion.methods._labels import method_label, parse_value
from fusion.methods._registry import (
    FillMethod,
    MethodVariant,
    ResolvedMethod,
    check_params,
    coerce_params,
    get_method,
    parse_label,
)
from sim.validation import ParameterError

__all__ = ["fill_request", "method_variants", "parse_param"]

_TERMS = {"method": "method", "param": "param"}
"""The library's wording of the two parameters these messages name."""


def _refusal(message: str) -> ParameterError:
    return ParameterError(message, **_TERMS)


def parse_param(text: str) -> tuple[str | None, str, object]:
    """A setting ``[METHOD.]KEY=VALUE`` apart: METHOD (None without), KEY and VALUE
    (:func:`fusion.methods.parse_value`).

    Raises
    ------
    sim.validation.ParameterError
        Not of that form, or a value that is not a finite number where it reads as one; names
        the parameter ``param``.
    """
    left, equals, value = text.partition("=")
    scope, dot, key = left.strip().rpartition(".")
    flag = f"{{param}} {ParameterError.literal(text)}"
    if not equals or not key.isidentifier() or (dot and not scope):
        raise _refusal(f"{flag}: expected KEY=VALUE, or METHOD.KEY=VALUE for one method's "
                       "(e.g. {param} plane.residual_rel=0.03)")
    try:
        return scope or None, key, parse_value(value)
    except ValueError:
        raise _refusal(f"{flag}: expected a finite number") from None


def method_variants(methods: Sequence[str], params: Sequence[str] = (), single: bool = False
                    ) -> list[MethodVariant]:
    """Method labels (``NAME`` or ``NAME{KEY=VALUE,...}``) with the settings of ``params``
    applied, checked and coerced.

    ``METHOD.KEY=VALUE`` sets KEY for every entry of METHOD; a bare ``KEY=VALUE`` for the one
    entry (refused with several: whose would it be?). A key set twice for one entry is refused.

    Parameters
    ----------
    methods : sequence of str
        The labels (``evfuse ... --method``).
    params : sequence of str
        The settings (``--param``, :func:`parse_param`).
    single : bool
        The one method of a fill (``evfuse fill`` / ``run``: given or the default).

    Returns
    -------
    list of MethodVariant
        One per label, its settings checked (:func:`fusion.methods.check_params`).

    Raises
    ------
    sim.validation.ParameterError
        Naming the parameter (``method`` or ``param``) and the entry, the method and what was
        expected.
    """
    return [MethodVariant(method.name, settings)
            for method, settings in _checked_methods(methods, params, single)]


def _checked_methods(methods: Sequence[str], params: Sequence[str], single: bool
                     ) -> list[tuple[FillMethod, dict]]:
    """:func:`method_variants`' work: each method found once, with its settings checked."""
    literal = ParameterError.literal
    entries = []                          # (method, settings, the entry that set each key)
    for text in methods:
        try:
            variant = parse_label(text)
        except MethodError as exc:
            raise _refusal(f"{{method}} {literal(exc)}") from None
        try:
            method = get_method(variant.spec)
            settings = coerce_params(method, variant.params)
        except MethodError as exc:
            raise _refusal(f"{{method}} {literal(text)}: {literal(exc)}") from None
        entries.append((method, settings, dict.fromkeys(settings, f"{{method}} {literal(text)}")))
    given = literal(", ".join(method_label(method.name, settings)
                              for method, settings, _ in entries))
    for text in params:
        flag = f"{{param}} {literal(text)}"
        scope, key, value = parse_param(text)
        if scope is None and len(entries) != 1:
            if not entries:
                raise _refusal(f"{flag}: no {{method}} given; {{param}} sets the settings of the "
                               "{method} ones")
            raise _refusal(f"{flag}: {len(entries)} methods given ({given}), whose is it? "
                           f"Write {{param}} METHOD.{key}=... (every entry of METHOD) or "
                           f"{{method}} 'METHOD{{{{{key}=...}}}}' (that entry)")
        targets = [entry for entry in entries if scope in (None, entry[0].name)]
        if not targets:
            if single:
                raise _refusal(f"{flag}: the filling method is {given}, not {literal(scope)}")
            raise _refusal(f"{flag}: {literal(scope)} is not among the {{method}} ones "
                           f"({given or 'none'}); {{param}} sets their settings only")
        for method, settings, flags in targets:
            if key in settings:
                raise _refusal(f"{flag}: {key} of {literal(method.name)} is already set by "
                               f"{flags[key]}; set it once")
            try:
                settings.update(coerce_params(method, {key: value}))
            except MethodError as exc:
                raise _refusal(f"{flag}: {literal(exc)}") from None
            flags[key] = flag
    for method, settings, flags in entries:
        try:
            check_params(method, settings)
        except MethodError as exc:
            raise _refusal(f"{' '.join(dict.fromkeys(flags.values()))}: {literal(exc)}") from None
    return [(method, settings) for method, settings, _ in entries]


def fill_request(method: str | None, params: Sequence[str] = (), *,
                 weighting: str | None = None, stages: DenseParams | None = None
                 ) -> ResolvedMethod:
    """The one filling method of a fill asked for as text, resolved (once) with its settings
    and the fill stage's parameters: what ``evfuse fill`` and ``evfuse run`` run.

    Parameters
    ----------
    method : str or None
        Its label (``NAME`` or ``NAME{KEY=VALUE,...}``); None: the paper's with ``weighting``
        (``paper-idw`` without).
    params : sequence of str
        Its settings, ``[METHOD.]KEY=VALUE`` (:func:`method_variants`).
    weighting : str or None
        The weighting asked for, None where none was.
    stages : DenseParams, optional
        The stage parameters asked for (default the paper's): the method refuses those it
        does not use set off their defaults
        (:meth:`fusion.methods.FillMethod.requested_stages`).

    Returns
    -------
    ResolvedMethod

    Raises
    ------
    sim.validation.ParameterError
        A bad setting (:func:`method_variants`) or two parameters that contradict each other.
    """
    spec = method or f"paper-{weighting or 'idw'}"
    [(found, settings)] = _checked_methods([spec], params, single=True)
    stages = found.requested_stages(stages or DenseParams(), weighting, settings, spec)
    return ResolvedMethod(found, settings, stages)
