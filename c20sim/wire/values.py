"""Frozen dataclasses built at the price of plain ones, for the values every request makes.

A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__`` looked up anew per field:
about 1 us for a frame-log record of 13 fields, where a plain class takes 0.15 us. Every request makes
several such values (its framing event, the decoded request and response, two frame-log records, the
reply), so that cost is a tenth of the request path. :func:`quick_init` gives a frozen, slotted
dataclass an ``__init__`` that sets each slot through the slot's own descriptor, bound once: the same
signature, defaults and result, half the time. Everything else stays the dataclass's: a field still
cannot be assigned (``FrozenInstanceError``), equality, hashing and ``repr`` are unchanged.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

__all__ = ["quick_init"]

T = TypeVar("T")


def quick_init(cls: type[T]) -> type[T]:
    """Replace the generated ``__init__`` of ``cls``, a ``@dataclass(frozen=True, slots=True)``, with a faster one.

    Only plain fields are supported (the class's own, positional, with a default or none; no ``default_factory``,
    ``init=False``, ``kw_only``, ``InitVar``, ``ClassVar`` or ``__post_init__``): anything else raises TypeError here, at import, rather than building a wrong value.
    """
    if "__mypyc_attrs__" in cls.__dict__:  # a class compiled by mypyc: its __init__ is compiled already
        return cls
    params = getattr(cls, "__dataclass_params__", None)
    if params is None or not params.frozen or "__slots__" not in cls.__dict__:
        raise TypeError(f"{cls.__name__}: quick_init is for @dataclass(frozen=True, slots=True) classes")
    if hasattr(cls, "__post_init__"):
        raise TypeError(f"{cls.__name__}: quick_init does not call __post_init__")
    plain = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    if set(cls.__dataclass_fields__) != plain:  # type: ignore[attr-defined]
        raise TypeError(f"{cls.__name__}: quick_init takes plain fields only (no InitVar, no ClassVar)")
    namespace: dict[str, Any] = {}
    arguments: list[str] = []
    body: list[str] = []
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name not in cls.__dict__ or f.name == "self":  # a slot of a base class, or a name __init__ takes
            raise TypeError(f"{cls.__name__}.{f.name}: quick_init takes the fields of the class's own slots")
        if not f.init or f.kw_only or f.default_factory is not dataclasses.MISSING:
            raise TypeError(f"{cls.__name__}.{f.name}: quick_init takes positional fields with a plain default or none")
        if f.default is dataclasses.MISSING:
            arguments.append(f.name)
        else:
            namespace[f"_default_{f.name}"] = f.default
            arguments.append(f"{f.name}=_default_{f.name}")
        namespace[f"_set_{f.name}"] = cls.__dict__[f.name].__set__  # the slot's member descriptor
        body.append(f"    _set_{f.name}(self, {f.name})")
    source = f"def __init__(self, {', '.join(arguments)}) -> None:\n" + ("\n".join(body) or "    pass") + "\n"
    exec(source, namespace)  # the way dataclasses itself writes __init__
    init = namespace["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__doc__ = cls.__init__.__doc__
    try:
        type.__setattr__(cls, "__init__", init)
    except TypeError:  # an immutable (compiled) class keeps its own __init__
        return cls
    return cls
