"""Constrained scalar types for config structs: msgspec checks them when a config is decoded."""

from __future__ import annotations

from typing import Annotated

import msgspec

Positive = Annotated[float, msgspec.Meta(gt=0)]
"""A float above zero."""
NonNegative = Annotated[float, msgspec.Meta(ge=0)]
"""A float at or above zero."""
