"""Checking the JSON values of a sequence file, and the one-line error that names what is wrong.

``SequenceFormatError`` names the file, the key path (``annotations[3].rotation``) and what is wrong
with the value. The value types below are pydantic field types with the readers' rules: numbers are
JSON numbers (booleans and numeric strings refused), an integer may be written ``3.0``, arrays must
be finite. ``validate_at`` validates a value found at a key path and reports pydantic's first
problem as a ``SequenceFormatError``; ``problem`` is how a validator reports one.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Any, NoReturn, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, PlainValidator, TypeAdapter, ValidationError
from pydantic_core import PydanticCustomError

__all__ = [
    "ORTHONORMAL_TOL",
    "Bbox",
    "FrameIndex",
    "FrameRate",
    "ImageId",
    "Integer",
    "Matrix3",
    "Numbers",
    "PositiveInteger",
    "PositiveIntegerIfGiven",
    "ReaderModel",
    "RotationMatrix",
    "SequenceFormatError",
    "Text",
    "Vector3",
    "describe_value",
    "finite_array",
    "orthonormal_or_none",
    "problem",
    "read_json_document",
    "validate_at",
]

ORTHONORMAL_TOL = 1e-6  # our files' rotations: written from exact rotation matrices

_FORMAT_ERROR = "sequence_format"
_Validated = TypeVar("_Validated")


class SequenceFormatError(ValueError):
    """A sequence JSON is malformed or cannot be mapped; names the file, the key path and the problem."""

    def __init__(self, path: str | Path, where: str, problem: str) -> None:
        self.path = str(path)
        self.where = where
        self.problem = problem
        super().__init__(f"{path}: {where}: {problem}" if where else f"{path}: {problem}")


def describe_value(value: Any) -> str:
    """A value as an error message shows it: its type and its JSON, cut at 60 characters."""
    text = json.dumps(value, default=str)
    return f"{type(value).__name__} {text[:60] + '...' if len(text) > 60 else text}"


def problem(text: str, at: str = "") -> PydanticCustomError:
    """A validation problem to raise; ``at`` extends the key path it is raised at (``"[3].id"``)."""
    return PydanticCustomError(_FORMAT_ERROR, "{problem}", {"problem": text, "at": at})


def orthonormal_or_none(R: np.ndarray, tol: float) -> np.ndarray | None:
    """R itself when it is a rotation within ``tol``, re-orthonormalised (SVD) if tol is loose."""
    if np.abs(R.T @ R - np.eye(3)).max() > tol or abs(np.linalg.det(R) - 1.0) > tol:
        return None
    if tol <= ORTHONORMAL_TOL:
        return R
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


class ReaderModel(BaseModel):
    """Base of the readers' models: frozen, unknown keys ignored, numpy arrays allowed as values."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True, extra="ignore")


# ====================================================================== values


def _integer(value: Any, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or int(value) != value:
        raise problem(f"must be an integer, got {describe_value(value)}")
    if minimum is not None and value < minimum:
        raise problem(f"must be >= {minimum}, got {value}")
    return int(value)


def _text(value: Any) -> str:
    if not isinstance(value, str):
        raise problem(f"must be a string, got {describe_value(value)}")
    return value


def _image_id(value: Any) -> int | str:
    return value if isinstance(value, str) else _integer(value)


def _frame_rate(value: Any) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not value > 0
        or not math.isfinite(value)
    ):
        raise problem(f"must be a positive number, got {describe_value(value)}")
    return float(value)


def _leaves(value: Any) -> Iterator[Any]:
    if isinstance(value, list):
        for item in value:
            yield from _leaves(item)
    else:
        yield value


def finite_array(value: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """Nested lists of finite numbers (booleans and strings refused) as a float64 array."""
    bad = next((x for x in _leaves(value) if isinstance(x, bool) or not isinstance(x, int | float)), None)
    if not isinstance(value, list) or bad is not None:
        raise problem(f"must be a list of numbers, got {describe_value(bad if bad is not None else value)}")
    try:
        array = np.asarray(value, dtype=np.float64)
    except ValueError:
        raise problem("rows of different lengths") from None
    if shape is not None and array.shape != shape:
        want, got = "x".join(map(str, shape)), "x".join(map(str, array.shape)) or "scalar"
        raise problem(f"must be {want} numbers, got shape {got}")
    if not np.all(np.isfinite(array)):
        raise problem("numbers must be finite")
    return array


def _shaped(*shape: int) -> Callable[[Any], np.ndarray]:
    return lambda value: finite_array(value, shape)


def _bbox(value: Any) -> tuple[float, float, float, float]:
    box = finite_array(value, (4,))
    if box[2] < 0 or box[3] < 0:
        raise problem(f"width and height must be >= 0, got {box.tolist()}")
    x, y, w, h = (float(v) for v in box)
    return x, y, w, h


def _rotation_matrix(value: Any) -> np.ndarray:
    raw = finite_array(value, (3, 3))
    R = orthonormal_or_none(raw, ORTHONORMAL_TOL)
    if R is None:
        raise problem(
            f"not a rotation matrix (R^T R = I and det R = 1 within {ORTHONORMAL_TOL:g}): {raw.tolist()}"
        )
    return R


Integer = Annotated[int, PlainValidator(_integer)]
PositiveInteger = Annotated[int, PlainValidator(lambda value: _integer(value, minimum=1))]
# A field declared ``PositiveIntegerIfGiven = None``: None when absent, but null is refused.
PositiveIntegerIfGiven = Annotated[int | None, PlainValidator(lambda value: _integer(value, minimum=1))]
FrameIndex = Annotated[int, PlainValidator(lambda value: _integer(value, minimum=0))]
Text = Annotated[str, PlainValidator(_text)]
ImageId = Annotated[int | str, PlainValidator(_image_id)]
FrameRate = Annotated[float, PlainValidator(_frame_rate)]
Numbers = Annotated[np.ndarray, PlainValidator(finite_array)]
Matrix3 = Annotated[np.ndarray, PlainValidator(_shaped(3, 3))]
Vector3 = Annotated[np.ndarray, PlainValidator(_shaped(3))]
Bbox = Annotated[tuple[float, float, float, float], PlainValidator(_bbox)]
RotationMatrix = Annotated[np.ndarray, PlainValidator(_rotation_matrix)]


# ====================================================================== reading and errors


def read_json_document(path: Path) -> dict:
    """The JSON object in ``path``; NaN and infinities refused.

    Raises
    ------
    FileNotFoundError
        ``path`` is not a file.
    SequenceFormatError
        Not UTF-8, not JSON, or not a JSON object.
    """
    if not path.is_file():
        raise FileNotFoundError(f"sequence JSON not found: {path}")

    def refuse_constant(name: str) -> NoReturn:
        raise SequenceFormatError(path, "", f"{name} is not valid JSON (numbers must be finite)")

    try:
        doc = json.loads(path.read_text(encoding="utf-8"), parse_constant=refuse_constant)
    except UnicodeDecodeError as exc:
        raise SequenceFormatError(path, "", f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise SequenceFormatError(
            path, f"line {exc.lineno} column {exc.colno}", f"invalid JSON: {exc.msg}"
        ) from None
    if not isinstance(doc, dict):
        raise SequenceFormatError(path, "top level", f"must be an object, got {describe_value(doc)}")
    return doc


def _key_path(where: str, loc: tuple[int | str, ...]) -> str:
    """``where`` extended by pydantic's location: ``("images", 3, "id")`` -> ``images[3].id``."""
    for part in loc:
        if isinstance(part, int):
            where += f"[{part}]"
        elif where:
            where += f".{part}"
        else:
            where = str(part)
    return where


def _format_error(path: Path, exc: ValidationError, where: str) -> SequenceFormatError:
    """The first problem pydantic found, as the one-line error of the file."""
    error = exc.errors(include_url=False)[0]
    kind, loc = error["type"], error["loc"]
    if kind == "missing":
        return SequenceFormatError(
            path, _key_path(where, loc[:-1]) or "top level", f"missing key {loc[-1]!r}"
        )
    if kind in ("model_type", "dict_type"):
        message = f"must be an object, got {describe_value(error['input'])}"
    elif kind == "list_type":
        message = f"must be a list, got {describe_value(error['input'])}"
    else:
        message = error["msg"]  # a ``problem`` raised by a validator
    at = error.get("ctx", {}).get("at", "") if kind == _FORMAT_ERROR else ""
    return SequenceFormatError(path, _key_path(where, loc) + at, message)


def validate_at(
    path: Path,
    schema: type[_Validated] | TypeAdapter[_Validated],
    value: Any,
    where: str = "",
    context: dict | None = None,
) -> _Validated:
    """``value``, found at key path ``where`` of ``path``, validated as ``schema`` (a model or an adapter).

    Raises
    ------
    SequenceFormatError
        The first problem, named by file and key path.
    """
    validate = schema.validate_python if isinstance(schema, TypeAdapter) else schema.model_validate
    try:
        return validate(value, context=context)
    except ValidationError as exc:
        raise _format_error(path, exc, where) from None
