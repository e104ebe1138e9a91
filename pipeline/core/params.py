"""Range checks for the plain parameter dataclasses of the algorithms.

Each parameter set is declared once, in the algorithm module that uses it, with its checks
in `__post_init__`; the Hydra schemas of `pipeline.app.config` subclass these dataclasses,
so the same check guards a config value and a direct call. A failed check raises
ParameterError naming the field; the app prefixes the config key.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import numbers
from collections.abc import Iterator
from typing import Any


class ParameterError(ValueError):
    """A parameter outside its allowed range: `field=value is not allowed (allowed: …)`."""

    def __init__(self, field: str, value: Any, allowed: str) -> None:
        self.field, self.value, self.allowed = field, value, allowed
        super().__init__(f"{field}={value} is not allowed (allowed: {allowed})")


def is_number(value: Any) -> bool:
    """A finite real number (bools are not numbers here)."""
    return (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and math.isfinite(value))


@contextlib.contextmanager
def renamed(obj: Any, old: str, new: str, section: str) -> Iterator[None]:
    """A renamed setting that still works for one release: its value moves to the new name,
    with one warning; the checks in the `with` block then name the spelling the user wrote
    (`expert.n_demos=0 is not allowed`, not `expert.n_starts=0`). Both given (the new one
    away from its default) is refused: the old spelling used to win silently over the new
    one."""
    value = getattr(obj, old)
    if value is None:
        yield
        return
    default = next(f.default for f in dataclasses.fields(obj) if f.name == new)
    require(getattr(obj, new) == default, old, value,
            f"{section}.{new} alone: {section}.{old} is its old name and both were given")
    logging.getLogger("pipeline").warning("%s.%s is deprecated and will be removed: use %s.%s",
                                          section, old, section, new)
    setattr(obj, new, value)
    setattr(obj, old, None)
    try:
        yield
    except ParameterError as e:
        if e.field != new:
            raise
        raise ParameterError(old, e.value, e.allowed) from None


def require(ok: bool, field: str, value: Any, allowed: str) -> None:
    if not ok:
        raise ParameterError(field, value, allowed)


# No positive setting (a radius, a gain, a rate, a duration) means anything beyond this; at
# 1e308 a config fuzz saw overflows surface as internal errors mid-run.
LARGEST_POSITIVE = 1e6


def require_positive(obj: Any, *fields: str) -> None:
    """Each named attribute of `obj` is a number > 0 and at most LARGEST_POSITIVE."""
    for name in fields:
        value = getattr(obj, name)
        require(is_number(value) and 0 < value <= LARGEST_POSITIVE, name, value,
                f"a number > 0 and <= {LARGEST_POSITIVE:g}")


# Lengths a scene can hold (m): far below them an integration step would take petabytes,
# far above them a decay length makes every cost equal to round-off.
SHORTEST_STEP = 1e-3
LONGEST_LENGTH = 1e4


def require_step(obj: Any, *fields: str) -> None:
    """Each named attribute of `obj` is an integration or lattice step of at least 1 mm."""
    for name in fields:
        value = getattr(obj, name)
        require(is_number(value) and SHORTEST_STEP <= value <= LONGEST_LENGTH, name, value,
                f"a step in metres from {SHORTEST_STEP:g} to {LONGEST_LENGTH:g}")


def require_length(obj: Any, *fields: str) -> None:
    """Each named attribute of `obj` is a length of at least 1 mm and at most LONGEST_LENGTH
    m (a config fuzz: radii of 1e-200 m divided by zero, room sides of 1e308 m overflowed)."""
    for name in fields:
        value = getattr(obj, name)
        require(is_number(value) and SHORTEST_STEP <= value <= LONGEST_LENGTH, name, value,
                f"a length in metres from {SHORTEST_STEP:g} to {LONGEST_LENGTH:g}")


def require_non_negative(obj: Any, *fields: str) -> None:
    for name in fields:
        value = getattr(obj, name)
        require(is_number(value) and value >= 0, name, value, "a finite number >= 0")


def require_count(obj: Any, *fields: str, minimum: int = 1, maximum: int | None = None) -> None:
    """Each named attribute of `obj` is an integer >= minimum (and <= maximum): one check,
    so that the config reference, which shows a key's first refusal, shows both bounds."""
    allowed = f"an integer >= {minimum}" if maximum is None else \
        f"an integer from {minimum} to {maximum:,}"
    for name in fields:
        value = getattr(obj, name)
        require(isinstance(value, numbers.Integral) and not isinstance(value, bool)
                and int(value) >= minimum and (maximum is None or int(value) <= maximum),
                name, value, allowed)
