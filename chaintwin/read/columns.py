"""Column maps: read exports whose headers are named otherwise.

A column map is a small YAML file (docs/data-contract.md, section 3) that maps each
exported header, exactly as written, to a canonical name and unit::

    columns:
      "Actual speed [1/min]": {name: speed, unit: rpm}
      "Zeit [ms]":            {name: time, unit: ms}

Headers it does not list are read as usual (``name [unit]``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from chaintwin.errors import ColumnMapError
from chaintwin.read.files import read_limited, yaml_load
from chaintwin.read.integers import refuse_huge_integers
from chaintwin.units import CANONICAL_CHANNELS

__all__ = ["ColumnMap", "ColumnTarget", "load_column_map"]


class ColumnTarget(BaseModel):
    """Where one exported header goes: a channel name and the unit of its values."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Annotated[str, Field(min_length=1)]
    unit: Annotated[str, Field(min_length=1)]

    @model_validator(mode="after")
    def _unit_accepted(self) -> ColumnTarget:
        spec = CANONICAL_CHANNELS.get(self.name)
        if spec is not None and self.unit not in spec.units:
            raise ValueError(
                f"unit '{self.unit}' is not accepted for {self.name}; "
                f"use one of {', '.join(spec.units)}"
            )
        return self


class ColumnMap(BaseModel):
    """Exported header (exactly as written) → canonical name and unit."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    columns: dict[str, ColumnTarget]

    @model_validator(mode="after")
    def _names_unique(self) -> ColumnMap:
        seen: dict[str, str] = {}
        for header, target in self.columns.items():
            if target.name in seen:
                raise ValueError(
                    f"headers '{seen[target.name]}' and '{header}' both map to "
                    f"'{target.name}'; map each channel once"
                )
            seen[target.name] = header
        return self

    def lookup(self, header: str) -> ColumnTarget | None:
        """Return the target of an exported header, or None when not mapped."""
        return self.columns.get(header.strip())


def load_column_map(path: str | Path) -> ColumnMap:
    """Read and validate a column map YAML file.

    Raises
    ------
    ColumnMapError
        Naming the file and the offending entry.
    """
    source = str(path)
    raw = read_limited(path, what="column map", error=lambda s, m: ColumnMapError(f"{s}: {m}"))
    try:
        data = yaml_load(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ColumnMapError(f"{source}: cannot read the column map ({exc})") from None
    except yaml.YAMLError:
        raise ColumnMapError(f"{source}: not valid YAML; fix the syntax") from None
    except RecursionError:
        raise ColumnMapError(f"{source}: nested too deeply to be a column map") from None
    refuse_huge_integers(data, source, ColumnMapError, "column map")
    if not isinstance(data, dict):
        raise ColumnMapError(
            f"{source}: a column map is a mapping with one key 'columns' (header → {{name, unit}})"
        )
    try:
        return ColumnMap.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        path_s = ".".join(str(p) for p in err["loc"]) or "(top level)"
        raise ColumnMapError(f"{source}: entry '{path_s}': {err['msg']}") from None
