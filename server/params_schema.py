"""The body of `PUT /api/params`, made from `Params`' own fields: the OpenAPI contract lists
every parameter with its type (three-vectors, the 3×3 H, the screen geometry), a request with an
unknown name, a wrong type (`false` is not a number here), NaN or Infinity is refused before
`Params` sees it, and nothing is mirrored by hand. Ranges stay `Params`' to check (its refusal
is a 422 too)."""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    create_model,
)

from gazehdr.sim import Params

_STRICT: dict[type, Any] = {
    float: StrictInt | StrictFloat,
    int: StrictInt,
    str: StrictStr,
    bool: StrictBool,
}


def _strict(kind: Any) -> Any:
    """`kind` with its numbers and strings strict (JSON's true is no number), tuples kept."""
    if kind in _STRICT:
        return _STRICT[kind]
    if dataclasses.is_dataclass(kind):
        return _model_of(kind)
    if typing.get_origin(kind) is tuple:
        return tuple[tuple(_strict(a) for a in typing.get_args(kind))]  # type: ignore[misc]
    raise TypeError(f"no schema for a parameter of type {kind!r}")


def _default(f: dataclasses.Field) -> Any:
    if f.default_factory is not dataclasses.MISSING:
        return Field(default_factory=f.default_factory)
    return f.default


def _model_of(cls: type) -> type[BaseModel]:
    """A model with `cls`' fields, each optional (its default shown) and none nullable."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: (_strict(hints[f.name]), _default(f)) for f in dataclasses.fields(cls)}
    config = ConfigDict(extra="forbid", allow_inf_nan=False)
    return create_model(cls.__name__, __config__=config, **fields)


#: Some or all of the parameters, by name; what is left out keeps its value.
ParamsChange = _model_of(Params)


def changed(body: BaseModel) -> dict[str, Any]:
    """The parameters a request named, as `Params.from_dict` takes them."""
    return body.model_dump(exclude_unset=True)
