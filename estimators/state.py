"""A pipeline's complete state as plain data, and back (pipeline snapshots).

:func:`dump` turns an object graph (the pipeline, its stages, the run around it) into bytes
of plain data — MessagePack of numbers, strings, lists and raw array bytes — and
:func:`load` rebuilds an equal graph. No code is ever named by the data beyond a class of an
allowed module, created empty (``cls.__new__``) and given its attributes: unlike pickle,
loading never calls a constructor, a ``__reduce__`` or any other callable of the data's
choosing.

One small protocol, Python's own: a class's state is ``obj.__getstate__()`` (by default its
``__dict__`` and slots) and is put back by its ``__setstate__`` if it defines one, else
attribute by attribute. A stage whose state is not plain data (a foreign extension object)
defines both; a stage that only holds numbers, arrays, containers and other stages needs
nothing, so stages gain fields without touching this module. Shared references stay shared
(the pipeline's ``quality`` is one object seen by three stages) and cycles are allowed.

Foreign objects: ``vqf.VQF`` (a C++ extension) is stored as its constructor's sample
times, its parameters and ``VQF.state`` (all floats), which restores it exactly.

``external``: objects that are not state but context (open files, the live counters, the
session's parameters) are written as a name and supplied again by the loader.
"""

from __future__ import annotations

import enum
import importlib
from collections import deque
from collections.abc import Collection, Mapping
from typing import Any

import msgspec
import numpy as np
from vqf import VQF

# Classes of these modules may be rebuilt (the pipeline's and the run's around it).
ALLOWED_MODULES: tuple[str, ...] = ("estimators.",)


class StateError(ValueError):
    """The graph holds something that is not plain data, or the data is not a graph this
    module wrote (damaged, or of another version)."""


def _vqf_state(v: VQF) -> dict[str, Any]:
    c = v.coeffs
    return {
        "ts": [float(c["gyrTs"]), float(c["accTs"]), float(c["magTs"])],
        "params": dict(v.params),
        "state": {k: _plain(x) for k, x in v.state.items()},
    }


def _plain(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    return x


def _vqf_from(s: Mapping[str, Any]) -> VQF:
    gyr_ts, acc_ts, mag_ts = s["ts"]
    v = VQF(gyr_ts, acc_ts, mag_ts, **s["params"])
    v.state = {
        k: (np.asarray(x, np.float64) if isinstance(x, list) else x) for k, x in s["state"].items()
    }
    return v


class _Encoder:
    def __init__(self, external: Mapping[str, Any], allowed: tuple[str, ...]) -> None:
        self.allowed = allowed
        self.ids: dict[int, int] = {}
        self.keep: list[Any] = []  # the objects numbered (their ids stay theirs meanwhile)
        self.external = {id(obj): name for name, obj in external.items()}

    def _number(self, obj: Any) -> int:
        n = len(self.keep)
        self.ids[id(obj)] = n
        self.keep.append(obj)
        return n

    def enc(self, obj: Any) -> Any:
        t = type(obj)
        if obj is None or t is bool or t is float or t is str:
            return obj
        if t is int:
            return obj if -(1 << 63) <= obj < (1 << 64) else ["I", str(obj)]
        name = self.external.get(id(obj))
        if name is not None:
            return ["X", name]
        ref = self.ids.get(id(obj))
        if ref is not None:
            return ["R", ref]
        if t is bytes:
            return ["b", obj]
        if t is np.ndarray:
            if obj.dtype.hasobject or obj.dtype.fields is not None:
                raise StateError(f"array of {obj.dtype} is not plain data")
            n = self._number(obj)
            return ["A", n, obj.dtype.str, list(obj.shape), np.ascontiguousarray(obj).tobytes()]
        if isinstance(obj, np.generic):
            if obj.dtype.hasobject:
                raise StateError("numpy object scalar")
            return ["N", obj.dtype.str, obj.tobytes()]
        if t is list:
            n = self._number(obj)
            if set(map(type, obj)) <= _SCALARS:  # a list of numbers: as it is (in C)
                return ["L", n, obj]
            return ["L", n, [self.enc(x) for x in obj]]
        if t is dict:
            n = self._number(obj)
            return ["D", n, [[self.enc(k), self.enc(v)] for k, v in obj.items()]]
        if t is tuple:
            n = self._number(obj)
            if set(map(type, obj)) <= _SCALARS:
                return ["T", n, list(obj)]
            return ["T", n, [self.enc(x) for x in obj]]
        if t is deque:
            n = self._number(obj)
            return ["Q", n, obj.maxlen, [self.enc(x) for x in obj]]
        if t is set or t is frozenset:
            n = self._number(obj)
            return ["S" if t is set else "F", n, [self.enc(x) for x in obj]]
        if t is VQF:
            n = self._number(obj)
            return ["V", n, self.enc(_vqf_state(obj))]
        cls = _qualname(t)
        if isinstance(obj, enum.Enum):
            return ["E", cls, self.enc(obj.value)]
        if not t.__module__.startswith(self.allowed):
            raise StateError(f"{cls} is not allowed in a snapshot")
        n = self._number(obj)
        base = next((b for b in _VALUE_BASES if isinstance(obj, b)), None)
        if base is not None:  # a float carrying extras (a cycle boundary): its value too
            return ["O", n, cls, self.enc(obj.__getstate__()), base(obj)]
        return ["O", n, cls, self.enc(obj.__getstate__())]


_VALUE_BASES: tuple[type, ...] = (float, int, str)


# scalars msgspec writes as they are (ints only within MessagePack's range: checked)
_SCALARS = frozenset({float, bool, str, type(None)})


def _qualname(t: type) -> str:
    return f"{t.__module__}:{t.__qualname__}"


class _Decoder:
    def __init__(self, external: Mapping[str, Any], allowed: tuple[str, ...]) -> None:
        self.objs: dict[int, Any] = {}
        self.external = external
        self.allowed = allowed

    def _class(self, name: str) -> type:
        module, _, qual = name.partition(":")
        if not module.startswith(self.allowed) or not qual or "<" in qual:
            raise StateError(f"class {name!r} is not allowed")
        obj: Any = importlib.import_module(module)
        for part in qual.split("."):
            obj = getattr(obj, part)
        if not isinstance(obj, type):
            raise StateError(f"{name!r} is not a class")
        return obj

    def dec(self, x: Any) -> Any:
        if not isinstance(x, list):
            return x
        tag = x[0]
        if tag == "R":
            return self.objs[x[1]]
        if tag == "X":
            return self.external[x[1]]
        if tag == "I":
            return int(x[1])
        if tag == "b":
            return bytes(x[1])
        if tag == "N":
            return np.frombuffer(x[2], dtype=np.dtype(x[1]))[0].copy()
        if tag == "E":
            cls = self._class(x[1])
            if not issubclass(cls, enum.Enum):
                raise StateError(f"{x[1]!r} is not an enum")
            return cls(self.dec(x[2]))
        n = x[1]
        if tag == "A":
            a = np.frombuffer(x[4], dtype=np.dtype(x[2])).reshape(x[3]).copy()
            self.objs[n] = a
            return a
        if tag == "L":
            out_l: list[Any] = []
            self.objs[n] = out_l
            out_l.extend(self.dec(v) for v in x[2])
            return out_l
        if tag == "D":
            out_d: dict[Any, Any] = {}
            self.objs[n] = out_d
            for k, v in x[2]:
                out_d[self.dec(k)] = self.dec(v)
            return out_d
        if tag == "Q":
            out_q: deque[Any] = deque(maxlen=x[2])
            self.objs[n] = out_q
            out_q.extend(self.dec(v) for v in x[3])
            return out_q
        if tag in ("T", "S", "F"):
            items = [self.dec(v) for v in x[2]]
            made: Any = (
                tuple(items) if tag == "T" else set(items) if tag == "S" else frozenset(items)
            )
            self.objs[n] = made
            return made
        if tag == "V":
            v = _vqf_from(self.dec(x[2]))
            self.objs[n] = v
            return v
        if tag == "O":
            made_cls: Any = self._class(x[2])
            if len(x) > 4:  # the builtin's own constructor, never the subclass's
                base: Any = next(b for b in _VALUE_BASES if issubclass(made_cls, b))
                obj = base.__new__(made_cls, x[4])
            else:
                obj = made_cls.__new__(made_cls)
            self.objs[n] = obj
            _set_state(obj, self.dec(x[3]))
            return obj
        raise StateError(f"unknown tag {tag!r}")


def _set_state(obj: Any, state: Any) -> None:
    """As pickle does: the class's ``__setstate__``, else ``__dict__`` and slots."""
    setter = getattr(type(obj), "__setstate__", None)
    if setter is not None:
        setter(obj, state)
        return
    slots: Mapping[str, Any] | None = None
    if isinstance(state, tuple) and len(state) == 2:
        state, slots = state
    if state:
        obj.__dict__.update(state)
    for k, v in (slots or {}).items():
        object.__setattr__(obj, k, v)


def dump(
    obj: Any,
    external: Mapping[str, Any] | None = None,
    allowed: Collection[str] = ALLOWED_MODULES,
) -> bytes:
    """``obj``'s graph as bytes; ``external``: objects written as their name only;
    ``allowed``: the modules whose classes the graph may hold."""
    try:
        tree = _Encoder(external or {}, tuple(allowed)).enc(obj)
        return msgspec.msgpack.encode(tree)
    except (TypeError, RecursionError, OverflowError) as exc:
        raise StateError(str(exc)) from exc


def load(
    data: bytes,
    external: Mapping[str, Any] | None = None,
    allowed: Collection[str] = ALLOWED_MODULES,
) -> Any:
    """The graph :func:`dump` wrote; ``external`` supplies the named objects."""
    try:
        tree = msgspec.msgpack.decode(data)
        return _Decoder(external or {}, tuple(allowed)).dec(tree)
    except StateError:
        raise
    except Exception as exc:  # damaged data of any kind: refused, never half-trusted
        raise StateError(f"{type(exc).__name__}: {exc}") from exc
