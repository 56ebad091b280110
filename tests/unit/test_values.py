"""quick_init: a frozen dataclass's faster __init__ builds exactly the value the dataclass's own would."""

from __future__ import annotations

import dataclasses
from dataclasses import InitVar, dataclass, field
from typing import ClassVar

import pytest

from c20sim.core.bus import Direction, FrameRecord, RecordKind
from c20sim.wire.protocol import ReadRequest
from c20sim.wire.values import quick_init


@dataclass(frozen=True, slots=True)
class Plain:
    a: int
    b: str = "b"
    c: tuple[int, ...] = ()
    d: object = field(default=None, compare=False)


@quick_init
@dataclass(frozen=True, slots=True)
class Quick:  # the same fields, with quick_init's __init__
    a: int
    b: str = "b"
    c: tuple[int, ...] = ()
    d: object = field(default=None, compare=False)


@pytest.mark.parametrize(
    ("args", "kwargs"),
    [((1,), {}), ((1, "x"), {}), ((1,), {"c": (2, 3)}), ((), {"a": 4, "d": "ignored by eq"}), ((1, "x", (5,), 6), {})],
)
def test_the_same_value_as_the_dataclasses_own_init(args: tuple[object, ...], kwargs: dict[str, object]) -> None:
    plain, quick = Plain(*args, **kwargs), Quick(*args, **kwargs)
    assert dataclasses.astuple(quick) == dataclasses.astuple(plain)  # type: ignore[call-overload]
    assert repr(quick).replace("Quick", "Plain") == repr(plain)
    assert hash(quick) == hash(Quick(*args, **kwargs)) and quick == Quick(*args, **kwargs)
    with pytest.raises(dataclasses.FrozenInstanceError):
        quick.a = 2


def test_a_missing_or_unknown_argument_is_refused_as_by_any_init() -> None:
    with pytest.raises(TypeError):
        Quick()
    with pytest.raises(TypeError):
        Quick(1, e=2)


def test_classes_it_cannot_build_are_refused_at_import() -> None:
    @dataclass(frozen=True, slots=True)
    class Posted:
        a: int

        def __post_init__(self) -> None:
            pass

    @dataclass(frozen=True, slots=True)
    class Factory:
        a: list[int] = field(default_factory=list)

    @dataclass(slots=True)
    class Thawed:
        a: int

    @dataclass(frozen=True, slots=True, kw_only=True)
    class Keywords:
        a: int

    @dataclass(frozen=True, slots=True)
    class Init:
        a: int
        b: InitVar[int] = 0

    @dataclass(frozen=True, slots=True)
    class Shared:
        a: int
        limit: ClassVar[int] = 3

    @dataclass(frozen=True, slots=True)
    class Derived(Plain):  # its base's fields are the base's slots
        e: int = 0

    for cls in (Posted, Factory, Thawed, Keywords, Init, Shared, Derived):
        with pytest.raises(TypeError, match=cls.__name__):
            quick_init(cls)


def test_the_values_of_every_request_are_built_whole() -> None:
    request = ReadRequest(1, 0x2001, 2)
    record = FrameRecord(1.5, Direction.RX, b"\x01", RecordKind.REQUEST, 1, "words", model_t=2.0, request=request)
    assert [getattr(record, f.name) for f in dataclasses.fields(record)] == [
        1.5,
        Direction.RX,
        b"\x01",
        RecordKind.REQUEST,
        1,
        "words",
        "",
        2.0,
        None,
        request,
        None,
        None,
        False,
    ]
    assert request == ReadRequest(slave=1, start=0x2001, count=2) and request.function == 0x03
