"""One JSON round trip for every result: typed objects out, the same objects back.

Results are frozen dataclasses (with numpy arrays, enums, tuples and nested results
inside them).  :func:`encode` writes any of them as JSON-native values and
:func:`decode` rebuilds the very objects, so a result saved by one run is read back
by another as the typed object, not as a dict to walk by string keys:

* a dataclass becomes ``{"$type": "module:Class", <field>: <value>, ...}`` (every
  field that takes part in ``__init__``);
* an ``ndarray`` becomes ``{"$array": [...], "dtype": "float64"}`` (its shape kept);
* a tuple becomes ``{"$tuple": [...]}``, an enum member
  ``{"$enum": "module:Class", "value": ...}``, a non-finite float
  ``{"$float": "nan" | "inf" | "-inf"}`` and a mapping proxy a plain dict;
* numpy scalars become Python numbers, dicts keep their (string) keys in order.

Python writes floats in JSON with ``repr``, which reads back bit for bit, so a round
trip is exact.  :func:`dumps` and :func:`loads` wrap the payload with the schema's
name and :data:`SCHEMA_VERSION`; :func:`loads` refuses another schema or another
version with a one-line :class:`~stictiondiag.core.errors.DataError` (a newer one:
upgrade; an older one: analyse the record again).

Only classes of this package are rebuilt: a ``$type`` or ``$enum`` outside
``stictiondiag`` is refused, so reading a file never imports foreign code.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import math
from enum import Enum
from types import MappingProxyType
from typing import Any

import numpy as np

from stictiondiag.core.errors import DataError

#: Version of the encoding below; raised when a change would misread older files.
#: 2: the replay holds its identified process and controller once, as typed fits.
#: 3: one process fit for both objectives, its extras typed (``ProcessFit.detail``).
#: 4: the replay's record, per-signal measures and settings typed (``replay.result``).
#: 5: a stiction fit's determinacy and gain sign are typed fields, not in ``details``.
#: 6: and so are its valve model and the valve's state where the model starts.
#: 7: and its drift comparison and disturbance model (a fit without mv).
#: 8: the stiction fit's result types live in ``stiction.fit_result``.
#: 9: a fit without mv's linear part is a typed field (``StictionFit.linear_part``),
#: and the closed-loop refit holds its processes as typed models.
#: 10: the verdict's evidence is typed (``VerdictEvidence``), its status and causes
#: enums (``VerdictStatus``, ``Cause``) and the cause model's reading a ``CauseReading``; a stiction fit's
#: period, interval method, block costs and archive resolution are typed fields;
#: an oscillation's absence is a category (``Absence``).
#: 11: the gap diagnosis is typed all the way down: its breakdown (``gap.breakdown``),
#: base replay (``GapBase``, the controller a ``ControllerReplay``), series
#: (``GapSeries``) and each candidate's parameters (the effect's ``EffectParams``).
#: 12: a stiction fit's ``details`` is typed per method (``MvFitDetails``,
#: ``HammersteinDetails`` in ``stiction.fit_details``), not a dict.
SCHEMA_VERSION = 12

#: The package whose classes :func:`decode` rebuilds.
_PACKAGE = "stictiondiag"


def _name(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _load_class(name: str) -> type:
    module, _, qualname = str(name).partition(":")
    if not (module == _PACKAGE or module.startswith(_PACKAGE + ".")) or not qualname:
        raise DataError(f"result file names a class outside {_PACKAGE}: {name!r}")
    try:
        obj: Any = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError):
        raise DataError(f"result file names an unknown class {name!r}") from None
    if not isinstance(obj, type):
        raise DataError(f"result file names {name!r}, which is not a class")
    return obj


def encode(value: Any) -> Any:
    """``value`` as JSON-native values (see the module docstring)."""
    if isinstance(value, Enum):
        return {"$enum": _name(type(value)), "value": encode(value.value)}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out: dict[str, Any] = {"$type": _name(type(value))}
        for spec in dataclasses.fields(value):
            if spec.init:
                out[spec.name] = encode(getattr(value, spec.name))
        return out
    if isinstance(value, np.ndarray):
        return {
            "$array": encode(value.tolist()),
            "dtype": value.dtype.str,
            "shape": list(value.shape),
        }
    if isinstance(value, dict | MappingProxyType):
        return {str(k): encode(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return {"$tuple": [encode(v) for v in value]}
    if isinstance(value, list):
        return [encode(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        f = float(value)
        if math.isfinite(f):
            return f
        return {"$float": "nan" if math.isnan(f) else ("inf" if f > 0 else "-inf")}
    if value is None or isinstance(value, str):
        return value
    raise TypeError(f"cannot encode a {type(value).__name__} in a result")


def decode(value: Any) -> Any:
    """The objects :func:`encode` wrote, rebuilt."""
    if isinstance(value, list):
        return [decode(v) for v in value]
    if not isinstance(value, dict):
        return value
    if "$type" in value:
        cls = _load_class(value["$type"])
        if not dataclasses.is_dataclass(cls):
            raise DataError(f"result file names {value['$type']!r}, which is not a result")
        kwargs = {k: decode(v) for k, v in value.items() if k != "$type"}
        try:
            return cls(**kwargs)
        except TypeError as exc:
            raise DataError(f"result file does not fit {value['$type']}: {exc}") from None
    if "$array" in value:
        data = decode(value["$array"])
        arr = np.array(data, dtype=np.dtype(value.get("dtype", "float64")))
        return arr.reshape(value.get("shape", arr.shape))
    if "$tuple" in value:
        return tuple(decode(v) for v in value["$tuple"])
    if "$enum" in value:
        return _load_class(value["$enum"])(decode(value["value"]))
    if "$float" in value:
        return float(value["$float"])
    return {k: decode(v) for k, v in value.items()}


def dumps(result: Any, *, schema: str) -> str:
    """``result`` as a JSON document of ``schema`` at :data:`SCHEMA_VERSION`."""
    payload = {"schema": schema, "version": SCHEMA_VERSION, "result": encode(result)}
    return json.dumps(payload, allow_nan=False)


def loads(text: str, *, schema: str) -> Any:
    """The result of a :func:`dumps` document of ``schema``.

    Raises
    ------
    DataError
        Not JSON, another schema, a newer version, or a class this package does
        not have.
    """
    try:
        payload = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataError(f"not a result file: {exc}") from None
    if not isinstance(payload, dict) or payload.get("schema") != schema:
        found = payload.get("schema") if isinstance(payload, dict) else None
        raise DataError(f"not a {schema} result file (schema {found!r})")
    version = payload.get("version")
    if not isinstance(version, int) or version > SCHEMA_VERSION:
        raise DataError(
            f"{schema} result file of version {version!r}: this stiction reads up to "
            f"version {SCHEMA_VERSION}; upgrade it"
        )
    if version < SCHEMA_VERSION:
        raise DataError(
            f"{schema} result file of version {version}, written by an older stiction: "
            f"analyse the record again to write it at version {SCHEMA_VERSION}"
        )
    return decode(payload.get("result"))
