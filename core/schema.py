"""Fields declared once with their constraints, checked without importing pydantic.

A frozen dataclass declares each field as `name: T = knob(default, ge=..., description=...)`
(bounds inside a type: `Annotated[float, Bounds(ge=0)]`), converts its raw values with
`@before("name")` functions and checks the whole with `@after` methods; its `__post_init__`
calls `check`. A cold command line builds options and settings before its first image, and
importing pydantic and building its schemas cost a seventh of that process's CPU, so:

- `check` accepts what is already of its field's type, and the text of a number, boolean or
  path (a query, a flag, an ASSET_PREVIEW_* variable), converting them as pydantic's lax mode
  does (tests/test_schema.py holds the two side by side);
- anything else, and every refusal, goes to `pydantic_class(cls)`, a pydantic dataclass built
  on first need from the same declaration: it converts what pydantic converts and raises
  pydantic's ValidationError, so errors read and nest as they did when the classes were
  pydantic dataclasses;
- the service's pydantic models take their fields from `pydantic_field` (the same declaration).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import re
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Callable, Literal, Union


@dataclasses.dataclass(frozen=True)
class Bounds:
    """Constraints on a value: numbers (ge, le, gt), lengths of text and tuples, a regex."""
    ge: float | None = None
    le: float | None = None
    gt: float | None = None
    min_length: int | None = None
    max_length: int | None = None
    pattern: str | None = None

    def merged(self, other: Bounds | None) -> Bounds:
        if other is None:
            return self
        return Bounds(**{**self.given(), **other.given()})

    def given(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if getattr(self, f.name) is not None}


NO_BOUNDS = Bounds()


def knob(default: Any, *, description: str | None = None, **bounds: Any) -> Any:
    """A dataclass field with its default, help text and bounds (`Bounds`' names)."""
    return dataclasses.field(default=default, metadata={"description": description, "bounds": Bounds(**bounds)})


def before(name: str) -> Callable[[Callable[[Any], Any]], Any]:
    """Decorate a function of a raw value: it runs before the field `name` is checked."""
    def mark(fn: Callable[[Any], Any]) -> Any:
        fn.checks_field = name  # type: ignore[attr-defined]
        return staticmethod(fn)
    return mark


def after(fn: Callable[[Any], None]) -> Callable[[Any], None]:
    """Decorate a method: it checks the whole object once every field is (ValueError if not)."""
    fn.checks_object = True  # type: ignore[attr-defined]
    return fn


@dataclasses.dataclass(frozen=True)
class Param:
    """One declared field: its resolved type, default, help and bounds."""
    annotation: Any
    default: Any
    description: str | None = None
    bounds: Bounds = NO_BOUNDS


class Refused(Exception):
    """A value the fast check does not take: pydantic decides (and words the error)."""


@dataclasses.dataclass(frozen=True)
class _Plan:
    names: tuple[str, ...]
    before: dict[str, Callable[[Any], Any]]
    convert: dict[str, Callable[[Any], Any]]
    after: tuple[Callable[[Any], None], ...]


def declared(cls: type) -> dict[str, Param]:
    """The fields of a `knob` dataclass, by name, in declaration order."""
    return dict(_declared(cls))


@functools.cache
def _declared(cls: type) -> dict[str, Param]:
    hints = typing.get_type_hints(cls, include_extras=True)
    out = {}
    for f in dataclasses.fields(cls):
        out[f.name] = Param(hints[f.name], f.default, f.metadata.get("description"),
                            f.metadata.get("bounds", NO_BOUNDS))
    return out


@functools.cache
def _plan(cls: type) -> _Plan:
    params = _declared(cls)
    befores: dict[str, Callable[[Any], Any]] = {}
    afters = []
    for klass in reversed(cls.__mro__[:-1]):  # not object
        for attr in vars(klass).values():
            fn = attr.__func__ if isinstance(attr, staticmethod) else attr
            name = getattr(fn, "checks_field", None)
            if name in params:
                befores[name] = fn
            elif getattr(fn, "checks_object", False):
                afters.append(fn)
    return _Plan(tuple(params), befores, {n: _converter(p.annotation, p.bounds) for n, p in params.items()},
                 tuple(afters))


def check(obj: Any) -> None:
    """Check and convert the fields of a `knob` dataclass in place (its `__post_init__`):
    pydantic's ValidationError when a value is refused."""
    cls: Any = type(obj)
    plan = _plan(cls)
    raw = {name: getattr(obj, name) for name in plan.names}
    values = fast_values(cls, raw)
    if values is None:
        values = _pydantic_values(cls, raw)  # raises pydantic's error, or converts what it converts
    for name, v in values.items():
        object.__setattr__(obj, name, v)
    try:
        for hook in plan.after:
            hook(obj)
    except ValueError:
        _pydantic_values(cls, raw)  # words the refusal (loc: the whole object)
        raise


def fast_values(cls: Any, raw: dict[str, Any]) -> dict[str, Any] | None:
    """Every field of `raw` (all of `cls`'s) checked and converted without pydantic, or None
    where one is not of a form this check takes (pydantic then decides)."""
    plan = _plan(cls)
    try:
        values = {}
        for name in plan.names:
            v = raw[name]
            fn = plan.before.get(name)
            values[name] = plan.convert[name](fn(v) if fn is not None else v)
    except (Refused, ValueError, OverflowError):  # OverflowError: an int too large for a float
        return None
    return values


def _pydantic_values(cls: type, raw: dict[str, Any]) -> dict[str, Any]:
    """`raw` validated by pydantic (its ValidationError when refused), as `cls`'s own values."""
    params = _declared(cls)
    nested = {n: t for n, p in params.items() if _is_checked(t := _strip_optional(p.annotation))}
    # what was given, as far as it shows: a refusal of the whole object quotes its input
    given = {n: v for n, v in raw.items() if v is not params[n].default}
    for name, target in nested.items():  # a nested object is valid already: pass its values
        if isinstance(given.get(name), target):
            given[name] = _values(given[name])
    model = pydantic_class(cls)(**given)
    out = {name: getattr(model, name) for name in params}
    for name, target in nested.items():
        if out[name] is not None:
            out[name] = target(**_values(out[name]))
    return out


def _values(obj: Any) -> dict[str, Any]:
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}


def _is_checked(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp) and "__post_init__" in vars(tp) \
        and any(isinstance(f.metadata.get("bounds"), Bounds) for f in dataclasses.fields(tp))


def _strip_optional(ann: Any) -> Any:
    if typing.get_origin(ann) in (Union, types.UnionType):
        args = [a for a in typing.get_args(ann) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return ann


# --- the fast check: one converter per field, built from its type once ----------------------

_INT_TEXT = re.compile(r"[ \t]*[+-]?[0-9]+[ \t]*")  # ASCII digits: pydantic refuses others
_FLOAT_TEXT = re.compile(r"[ \t]*[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?[ \t]*")
_TRUE = frozenset({"1", "on", "t", "true", "y", "yes"})
_FALSE = frozenset({"0", "off", "f", "false", "n", "no"})


def _refuse() -> typing.NoReturn:
    raise Refused


def _converter(ann: Any, bounds: Bounds) -> Callable[[Any], Any]:
    origin = typing.get_origin(ann)
    if origin is Annotated:
        base, *meta = typing.get_args(ann)
        for m in meta:
            bounds = bounds.merged(m if isinstance(m, Bounds) else None)
        return _converter(base, bounds)
    if origin in (Union, types.UnionType):
        inner = _strip_optional(ann)
        if inner is ann:
            raise TypeError(f"{ann}: only X | None unions are declared")
        convert = _converter(inner, bounds)
        return lambda v: None if v is None else convert(v)
    if origin is Literal:
        choices = typing.get_args(ann)
        return lambda v: v if any(v == c and type(v) is type(c) for c in choices) else _refuse()
    if origin is tuple:
        return _tuple_converter(typing.get_args(ann), bounds)
    if ann is bool:
        return _to_bool
    if ann is int or ann is float:
        return _number_converter(ann, bounds)
    if ann is str:
        return _text_converter(bounds)
    if ann is Path:
        return lambda v: v if isinstance(v, Path) else (Path(v) if type(v) is str else _refuse())
    if _is_checked(ann):
        def nested(v: Any) -> Any:
            if type(v) is ann:
                return v
            if type(v) is not dict:
                _refuse()
            try:
                return ann(**v)
            except Exception:  # noqa: BLE001 - the outer object's pydantic check words it, with its path
                raise Refused from None
        return nested
    raise TypeError(f"{ann}: not a type the fast check knows")


def _to_bool(v: Any) -> bool:
    if type(v) is bool:
        return v
    if type(v) is int and v in (0, 1):
        return bool(v)
    if type(v) is str:
        s = v.lower()  # no strip: pydantic refuses " true "
        if s in _TRUE:
            return True
        if s in _FALSE:
            return False
    _refuse()


def _number_converter(kind: type, bounds: Bounds) -> Callable[[Any], Any]:
    ge, le, gt = bounds.ge, bounds.le, bounds.gt

    def convert(v: Any) -> Any:
        t = type(v)
        if kind is int:
            if t is int:
                x: Any = v
            elif t is float and v.is_integer():
                x = int(v)
            elif t is str and _INT_TEXT.fullmatch(v):
                x = int(v)
            else:
                _refuse()
        else:
            if t is float or t is int:
                x = float(v)
            elif t is str and _FLOAT_TEXT.fullmatch(v):
                x = float(v)
            else:
                _refuse()
            if not math.isfinite(x):
                _refuse()
        if (ge is not None and not x >= ge) or (le is not None and not x <= le) or (gt is not None and not x > gt):
            _refuse()
        return x
    return convert


def _text_converter(bounds: Bounds) -> Callable[[Any], Any]:
    lo, hi = bounds.min_length, bounds.max_length
    pattern = re.compile(bounds.pattern) if bounds.pattern else None

    def convert(v: Any) -> Any:
        if type(v) is not str or (lo is not None and len(v) < lo) or (hi is not None and len(v) > hi) \
                or (pattern is not None and not pattern.search(v)):
            _refuse()
        return v
    return convert


def _tuple_converter(args: tuple, bounds: Bounds) -> Callable[[Any], Any]:
    lo, hi = bounds.min_length, bounds.max_length
    if len(args) == 2 and args[1] is Ellipsis:
        item = _converter(args[0], NO_BOUNDS)

        def variadic(v: Any) -> Any:
            if type(v) not in (tuple, list) or (lo is not None and len(v) < lo) or (hi is not None and len(v) > hi):
                _refuse()
            return tuple(item(x) for x in v)
        return variadic
    items = [_converter(a, NO_BOUNDS) for a in args]

    def fixed(v: Any) -> Any:
        if type(v) not in (tuple, list) or len(v) != len(items):
            _refuse()
        return tuple(f(x) for f, x in zip(items, v))
    return fixed


# --- pydantic, from the same declaration (the service; refusals) -----------------------------

def pydantic_annotation(ann: Any) -> Any:
    """`ann` as pydantic reads it: `Bounds` as pydantic's constraints, a nested `knob`
    dataclass as its pydantic class."""
    origin = typing.get_origin(ann)
    if origin is Annotated:
        from pydantic import Field
        base, *meta = typing.get_args(ann)
        extra = [Field(**m.given()) if isinstance(m, Bounds) else m for m in meta]
        args = (pydantic_annotation(base), *extra)
        return Annotated[args]  # type: ignore[valid-type]  # a tuple subscript, as Annotated[T, *meta]
    if origin in (Union, types.UnionType):
        return functools.reduce(lambda a, b: a | b, [pydantic_annotation(a) for a in typing.get_args(ann)])
    if origin is tuple:
        args = typing.get_args(ann)
        return tuple[tuple(a if a is Ellipsis else pydantic_annotation(a) for a in args)]  # type: ignore[misc]
    if _is_checked(ann):
        return pydantic_class(ann)
    return ann


def pydantic_field(p: Param) -> tuple[Any, Any]:
    """(annotation, pydantic FieldInfo) of a declared field, for pydantic's `create_model`."""
    from pydantic import Field
    return pydantic_annotation(p.annotation), Field(default=p.default, description=p.description, **p.bounds.given())


@functools.cache
def pydantic_class(cls: type) -> type:
    """A pydantic dataclass of `cls`'s declaration: the same fields, bounds, `before` and
    `after` checks, and the config `cls.PYDANTIC_CONFIG` names."""
    from pydantic import ConfigDict, field_validator, model_validator
    from pydantic.dataclasses import dataclass

    plan = _plan(cls)
    namespace: dict[str, Any] = {"__module__": cls.__module__, "__doc__": cls.__doc__,
                                 "__qualname__": cls.__qualname__}
    for name, fn in plan.before.items():
        namespace[f"before_{name}"] = field_validator(name, mode="before")(staticmethod(fn))
    for i, fn in enumerate(plan.after):
        namespace[f"after_{i}"] = model_validator(mode="after")(_returning_self(fn))
    annotations = {}
    for name, p in _declared(cls).items():
        annotations[name], namespace[name] = pydantic_field(p)
    namespace["__annotations__"] = annotations
    return dataclass(type(cls.__name__, (), namespace), config=ConfigDict(**getattr(cls, "PYDANTIC_CONFIG", {})))


def _returning_self(fn: Callable[[Any], None]) -> Callable[[Any], Any]:
    def hook(self: Any) -> Any:
        fn(self)
        return self
    hook.__name__ = fn.__name__
    return hook
