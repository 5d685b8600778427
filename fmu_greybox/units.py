"""Unit strings: one grammar for the whole package.

The FMU builder, the recording loader, the project file and the FMU binding all read unit
strings through this module. The syntax is UCUM-like, the syntax of Modelica and FMI units:

- ``.``, ``*``, ``·`` or a space multiply; ``/`` divides by the next factor only (``kg/m.s`` is
  kg·s/m; write ``kg/(m.s)``); a leading ``/`` means ``1/``;
- exponents as ``m3``, ``m^3``, ``m³``, ``s-1``; parentheses group;
- symbols are case-sensitive; ``1``, ``-``, ``none`` and the empty string are dimensionless.

Two levels: :func:`normalise_unit` gives a canonical *spelling* (no symbol needs to be known),
and :func:`si_unit` resolves the symbols to SI base units with a factor (and an offset for
``degC``), so that :func:`conversion` can say how to convert values between two units of the
same dimension (``mm`` to ``m``, ``bar`` to ``Pa``, ``ms`` to ``s``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

__all__ = [
    "BASE_UNITS",
    "PREFIXES",
    "SYMBOLS",
    "Conversion",
    "SiUnit",
    "UnitSyntaxError",
    "conversion",
    "normalise_unit",
    "si_unit",
    "units_compatible",
]

#: SI base units in the order FMI's ``BaseUnit`` lists them (``rad`` is FMI's eighth).
BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")

_PASCAL = {"kg": 1, "m": -1, "s": -2}
#: Known symbols: SI base-unit exponents and the factor to the coherent SI unit.
SYMBOLS: dict[str, tuple[dict[str, int], float]] = {
    **{base: ({base: 1}, 1.0) for base in BASE_UNITS},
    "g": ({"kg": 1}, 1e-3),
    "N": ({"kg": 1, "m": 1, "s": -2}, 1.0),
    "Pa": (_PASCAL, 1.0),
    "J": ({"kg": 1, "m": 2, "s": -2}, 1.0),
    "W": ({"kg": 1, "m": 2, "s": -3}, 1.0),
    "V": ({"kg": 1, "m": 2, "s": -3, "A": -1}, 1.0),
    "C": ({"A": 1, "s": 1}, 1.0),
    "Hz": ({"s": -1}, 1.0),
    "Ohm": ({"kg": 1, "m": 2, "s": -3, "A": -2}, 1.0),
    "H": ({"kg": 1, "m": 2, "s": -2, "A": -2}, 1.0),
    "bar": (_PASCAL, 1e5),
    "psi": (_PASCAL, 6894.757293168361),
    "L": ({"m": 3}, 1e-3),
    "min": ({"s": 1}, 60.0),
    "h": ({"s": 1}, 3600.0),
    "deg": ({"rad": 1}, math.pi / 180.0),
    "degC": ({"K": 1}, 1.0),
    "%": ({}, 1e-2),
}
#: Prefixes that may stand before any symbol of :data:`SYMBOLS` (``u`` is micro).
PREFIXES = {"G": 1e9, "M": 1e6, "k": 1e3, "h": 1e2, "c": 1e-2, "m": 1e-3, "u": 1e-6, "n": 1e-9}
#: Symbols measured from another zero than their SI unit: value in K = value + offset.
_OFFSETS = {"degC": 273.15}

_DIMENSIONLESS = {"", "1", "-", "none", "dimensionless"}
_ALIASES = {
    "sec": "s",
    "secs": "s",
    "°": "deg",
    "degree": "deg",
    "degrees": "deg",
    "°C": "degC",
    "l": "L",
    "ohm": "Ohm",
    "Ω": "Ohm",
}
_UNICODE = str.maketrans(
    {
        **dict(zip("⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺", "0123456789-+", strict=True)),
        "·": ".",
        "⋅": ".",
        "*": ".",
        "×": ".",
        "µ": "u",
        "μ": "u",
    }
)
_TOKEN = re.compile(r"(?P<num>\d+)|(?P<op>[./^()+\-])|(?P<sym>[^\d./^()+\-]+)")


class UnitSyntaxError(ValueError):
    """A unit string that does not follow the grammar, or names an unknown symbol."""


class _Parser:
    """Recursive-descent parser of unit strings into ``{symbol: power}``.

    ``expr := ['/'] factor (('.' | '/') factor)*``; ``factor := (symbol | '1' | '(' expr ')')
    [['^'] [sign] digits]``. A ``/`` divides by the next factor only, as in UCUM.
    """

    def __init__(self, text: str) -> None:
        self.tokens = [(m.lastgroup or "", m[m.lastgroup or 0]) for m in _TOKEN.finditer(text)]
        self.pos = 0

    def parse(self) -> dict[str, int]:
        powers = self._expr()
        if self.pos != len(self.tokens):
            raise UnitSyntaxError(f"unexpected {self.tokens[self.pos][1]!r}")
        return {symbol: power for symbol, power in powers.items() if power != 0}

    def _peek(self, *ops: str) -> bool:
        return self.pos < len(self.tokens) and self.tokens[self.pos] in [("op", o) for o in ops]

    def _next(self) -> tuple[str, str]:
        if self.pos >= len(self.tokens):
            raise UnitSyntaxError("unexpected end")
        self.pos += 1
        return self.tokens[self.pos - 1]

    def _expr(self) -> dict[str, int]:
        powers: dict[str, int] = {}
        sign = 1
        if self._peek("/"):
            self._next()
            sign = -1
        while True:
            for symbol, power in self._factor().items():
                powers[symbol] = powers.get(symbol, 0) + sign * power
            if not self._peek(".", "/"):
                return powers
            sign = -1 if self._next()[1] == "/" else 1

    def _factor(self) -> dict[str, int]:
        kind, value = self._next()
        if (kind, value) == ("op", "("):
            inner = self._expr()
            if self._next() != ("op", ")"):
                raise UnitSyntaxError("unbalanced parenthesis")
        elif kind == "sym":
            inner = {_ALIASES.get(value, value): 1}
        elif (kind, value) == ("num", "1"):
            inner = {}
        else:
            raise UnitSyntaxError(f"unexpected {value!r}")
        exponent = self._exponent()
        return {symbol: power * exponent for symbol, power in inner.items()}

    def _exponent(self) -> int:
        caret = self._peek("^")
        if caret:
            self._next()
        sign = -1 if self._peek("-") else 1
        signed = self._peek("-", "+")
        if signed:
            self._next()
        if self.pos < len(self.tokens) and self.tokens[self.pos][0] == "num":
            return sign * int(self._next()[1])
        if caret or signed:
            raise UnitSyntaxError("exponent without digits")
        return 1


def _powers(unit: str) -> dict[str, int]:
    """``{symbol: power}`` of a unit string (spellings unified, symbols not resolved).

    Raises
    ------
    UnitSyntaxError
        If the string does not follow the grammar.
    """
    text = unit.strip().translate(_UNICODE)
    if text.lower() in _DIMENSIONLESS:
        return {}
    text = re.sub(r"\s*([./^()])\s*", r"\1", text)
    text = re.sub(r"\s+", ".", text)
    return _Parser(text).parse()


def _format_powers(powers: Mapping[str, int]) -> str:
    """Canonical text: sorted numerator joined by '.', then '/'-separated denominator."""
    numerator = [f"{s}{p if p != 1 else ''}" for s, p in sorted(powers.items()) if p > 0]
    denominator = [f"{s}{-p if p != -1 else ''}" for s, p in sorted(powers.items()) if p < 0]
    if not numerator and not denominator:
        return ""
    return ".".join(numerator or ["1"]) + "".join("/" + d for d in denominator)


def normalise_unit(unit: str) -> str:
    """Canonical spelling of a unit, for comparisons (units are stored as given).

    Equivalent spellings map to one string: ``"m^3/s"``, ``"m3/s"``, ``"m³·s⁻¹"`` → ``"m3/s"``;
    ``"N·s/m"``, ``"N*s/m"``, ``"N s/m"`` → ``"N.s/m"``; ``""``, ``"1"``, ``"-"``, ``"none"`` →
    ``""`` (dimensionless or unknown); ``"µm"`` → ``"um"``; ``"sec"`` → ``"s"``. Prefixes are
    kept (``"mm"`` is not ``"m"``: see :func:`conversion`). A string that does not parse is
    returned stripped.

    Parameters
    ----------
    unit : str

    Returns
    -------
    str
    """
    try:
        return _format_powers(_powers(unit))
    except UnitSyntaxError:
        return unit.strip()


def units_compatible(a: str, b: str) -> bool:
    """Whether two unit strings denote the same unit up to spelling (see :func:`normalise_unit`).

    No conversion is attempted: ``units_compatible("mm", "m")`` is false. ``""`` (unknown or
    dimensionless) matches only ``""``, ``"1"``, ``"-"``; a caller that treats an empty recorded
    unit as *unknown* should skip the comparison.
    """
    return normalise_unit(a) == normalise_unit(b)


@dataclass(frozen=True)
class SiUnit:
    """A unit resolved to SI base units.

    Attributes
    ----------
    exponents : dict[str, int]
        Base unit (of :data:`BASE_UNITS`) -> exponent; zero exponents left out.
    factor : float
        Value in the coherent SI unit = value × factor + offset.
    offset : float
        Non-zero only for a unit measured from another zero (``degC``: 273.15).
    """

    exponents: dict[str, int]
    factor: float
    offset: float = 0.0


def _symbol(text: str) -> tuple[dict[str, int], float]:
    """Exponents and factor of one (possibly prefixed) symbol."""
    if text in SYMBOLS:
        return SYMBOLS[text]
    if len(text) > 1 and text[0] in PREFIXES and text[1:] in SYMBOLS:
        exponents, factor = SYMBOLS[text[1:]]
        return exponents, factor * PREFIXES[text[0]]
    raise UnitSyntaxError(f"unknown unit symbol {text!r}")


def si_unit(unit: str) -> SiUnit:
    """Resolve a unit string to SI base units.

    Parameters
    ----------
    unit : str
        E.g. ``"m3/(s.Pa)"``, ``"mA"``, ``"bar"``, ``"degC"``.

    Returns
    -------
    SiUnit

    Raises
    ------
    UnitSyntaxError
        If the string does not parse or names a symbol that is not in :data:`SYMBOLS` (with a
        prefix of :data:`PREFIXES`).
    """
    powers = _powers(unit)
    exponents: dict[str, int] = {}
    factor = 1.0
    for symbol, power in powers.items():
        base, scale = _symbol(symbol)
        for name, exponent in base.items():
            exponents[name] = exponents.get(name, 0) + exponent * power
        factor *= scale**power
    offset = 0.0
    if len(powers) == 1:
        [(symbol, power)] = powers.items()
        offset = _OFFSETS.get(symbol, 0.0) if power == 1 else 0.0
    return SiUnit({k: v for k, v in exponents.items() if v != 0}, factor, offset)


@dataclass(frozen=True)
class Conversion:
    """How values in one unit become values in another: ``new = old × scale + offset``."""

    scale: float
    offset: float = 0.0

    @property
    def identity(self) -> bool:
        """Whether the conversion leaves values unchanged."""
        return self.scale == 1.0 and self.offset == 0.0


def conversion(source: str, target: str) -> Conversion:
    """The conversion of values from unit ``source`` to unit ``target``.

    Two spellings of one unit convert by identity even when a symbol is unknown (``"furlong"``
    to ``"furlong"``).

    Raises
    ------
    UnitSyntaxError
        If either unit does not parse, names an unknown symbol, or the two differ in dimension
        (``"m"`` and ``"Pa"``); the message says which.
    """
    if units_compatible(source, target):
        return Conversion(1.0)
    a, b = si_unit(source), si_unit(target)
    if a.exponents != b.exponents:
        raise UnitSyntaxError(
            f"{source!r} and {target!r} measure different quantities "
            f"({_format_powers(a.exponents) or 'dimensionless'} against "
            f"{_format_powers(b.exponents) or 'dimensionless'})"
        )
    scale = a.factor / b.factor
    return Conversion(scale, (a.offset - b.offset) / b.factor)
