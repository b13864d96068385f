"""Typed commands: one class per command hartkit types, made from its command table.

    >>> from hartkit import commands
    >>> commands.ReadDynamicVariables.number
    3
    >>> r = commands.ReadDynamicVariables.decode_reply(data)
    >>> r.loop_current, r.variables[0].value, r.variables[0].units_symbol

Each class has ``number``, ``title``, ``kind`` ("universal", "common-practice",
"burst") and ``writes``; ``decode_reply(data)`` and ``decode_request(data)`` give a
``Record`` whose attributes are the command's fields (units, codes and status bits also
in words: ``units_symbol``, ``<code>_name``, ``<bits>_set``); ``Record.to_dict()`` gives
them back as a dict. ``by_number(n)`` finds a class by its number.

The other way, ``encode_request(**fields)`` and ``encode_reply(**fields)`` build the
data from the same names (a decoded Record or its dict goes back as it is; units and
codes may be given by name, ``pv_units="kPa"``; raw bytes as ``bytes`` or hex):

    >>> commands.WriteTagDescriptorDate.encode_request(
    ...     tag="PT-101", descriptor="FEED PUMP", date="2026-11-26").hex()
    '414b71c31820...'

A missing field, a key that is no field of the layout, a value out of range or a later
optional field given without an earlier one raises FrameError saying which.
"""

from typing import Any, Dict, List, Mapping, Optional, Type, Union

from ._native import (
    command_table,
    decode_reply as _decode_reply,
    decode_request as _decode_request,
    encode_reply as _encode_reply,
    encode_request as _encode_request,
)


class Record:
    """Fields as attributes (nested dicts as Records, lists of dicts as lists of
    Records); ``to_dict()`` for the plain dict."""

    __slots__ = ("_d",)

    def __init__(self, d: Dict[str, Any]):
        object.__setattr__(self, "_d", d)

    def __getattr__(self, name: str) -> Any:
        try:
            return _wrap(self._d[name])
        except KeyError:
            raise AttributeError(f"no field {name!r}; the fields are {', '.join(self._d)}") from None

    def __getitem__(self, name: str) -> Any:
        return _wrap(self._d[name])

    def __contains__(self, name: str) -> bool:
        return name in self._d

    def __dir__(self) -> List[str]:
        return list(self._d)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Record) and other._d == self._d

    def to_dict(self) -> Dict[str, Any]:
        """The fields as a plain dict."""
        return dict(self._d)

    def __repr__(self) -> str:
        fields = ", ".join(f"{k}={v!r}" for k, v in self._d.items())
        return f"{type(self).__name__}({fields})"


def _wrap(v: Any) -> Any:
    if isinstance(v, dict):
        return Record(v)
    if isinstance(v, list):
        return [_wrap(x) for x in v]
    return v


Fields = Union[Mapping[str, Any], Record, None]


def plain(fields: Fields = None, **kw: Any) -> Dict[str, Any]:
    """Fields as the plain dict the encoders take: a Record or mapping, plus keyword
    fields; Records inside become dicts, bytes become hex."""
    d: Dict[str, Any] = {}
    if isinstance(fields, Record):
        d.update(fields.to_dict())
    elif fields is not None:
        d.update(fields)
    d.update(kw)
    return {k: _plain(v) for k, v in d.items()}


def _plain(v: Any) -> Any:
    if isinstance(v, Record):
        return {k: _plain(x) for k, x in v.to_dict().items()}
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (bytes, bytearray, memoryview)):
        return bytes(v).hex()
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def encode_request(number: int, fields: Fields = None, **kw: Any) -> bytes:
    """The request data of command ``number`` built from its fields."""
    return _encode_request(number, plain(fields, **kw))


def encode_reply(number: int, fields: Fields = None, **kw: Any) -> bytes:
    """The reply data (after the status bytes) of command ``number`` built from its
    fields."""
    return _encode_reply(number, plain(fields, **kw))


class Command:
    """A command of the table; the classes below are its subclasses."""

    number: int = -1
    title: str = ""
    kind: str = ""
    writes: bool = False

    @classmethod
    def decode_reply(cls, data: bytes) -> Optional[Record]:
        """The reply data (after the status bytes) decoded; raises FrameError when
        the data does not fit the layout."""
        d = _decode_reply(cls.number, bytes(data))
        return None if d is None else Record(d)

    @classmethod
    def decode_request(cls, data: bytes) -> Optional[Record]:
        """The request data decoded."""
        d = _decode_request(cls.number, bytes(data))
        return None if d is None else Record(d)

    @classmethod
    def encode_request(cls, fields: Fields = None, **kw: Any) -> bytes:
        """The request data built from its fields (a Record, a dict, keywords)."""
        return encode_request(cls.number, fields, **kw)

    @classmethod
    def encode_reply(cls, fields: Fields = None, **kw: Any) -> bytes:
        """The reply data (after the status bytes) built from its fields."""
        return encode_reply(cls.number, fields, **kw)


_BY_NUMBER: Dict[int, Type[Command]] = {}

for _number, _name, _title, _kind, _writes in command_table():
    _cls = type(
        _name,
        (Command,),
        {
            "number": _number,
            "title": _title,
            "kind": _kind,
            "writes": _writes,
            "__doc__": f"Command {_number}: {_title} ({_kind}{', writes' if _writes else ''}).",
            "__module__": __name__,
        },
    )
    globals()[_name] = _cls
    _BY_NUMBER[_number] = _cls


def by_number(number: int) -> Optional[Type[Command]]:
    """The class of command ``number``, or None when hartkit does not type it."""
    return _BY_NUMBER.get(number)


def all_commands() -> List[Type[Command]]:
    """Every typed command, in number order."""
    return [_BY_NUMBER[n] for n in sorted(_BY_NUMBER)]
