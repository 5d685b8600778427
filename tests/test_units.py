"""One unit grammar for the FMU builder and the recordings (issue 16), and unit conversion."""

from __future__ import annotations

import math

import pytest

from fmu_greybox.errors import FmuBuildError
from fmu_greybox.fmi import variables
from fmu_greybox.units import UnitSyntaxError, conversion, normalise_unit, si_unit


@pytest.mark.parametrize(
    ("spelling", "exponents", "factor"),
    [
        # the builder refused these, the recording grammar read them
        ("/s", {"s": -1}, 1.0),  # a leading '/' is '1/'
        ("m^3/s", {"m": 3, "s": -1}, 1.0),  # '^' before an exponent
        ("N s/m", {"kg": 1, "s": -1}, 1.0),  # a space multiplies
        ("L/min", {"m": 3, "s": -1}, 1e-3 / 60),
        ("m³·s⁻¹", {"m": 3, "s": -1}, 1.0),
        # both read these alike: '/' divides by the next factor only
        ("kg/m.s", {"kg": 1, "m": -1, "s": 1}, 1.0),
        ("kg/(m.s)", {"kg": 1, "m": -1, "s": -1}, 1.0),
        ("m/s/s", {"m": 1, "s": -2}, 1.0),
        ("m3/(s.Pa)", {"m": 4, "kg": -1, "s": 1}, 1.0),
    ],
)
def test_builder_and_recordings_read_a_unit_alike(spelling, exponents, factor):
    built = variables.parse_unit(spelling)
    assert built[0] == exponents
    assert math.isclose(built[1], factor, rel_tol=1e-12)
    resolved = si_unit(spelling)
    assert (resolved.exponents, resolved.factor) == (built[0], built[1])
    # one canonical spelling: spellings of the same unit compare equal
    assert normalise_unit(spelling) == normalise_unit(normalise_unit(spelling))


def test_builder_names_an_unknown_symbol():
    with pytest.raises(FmuBuildError, match="unknown unit symbol 'furlong'"):
        variables.parse_unit("furlong/s")
    with pytest.raises(FmuBuildError, match="unit 'm/': unexpected end"):
        variables.parse_unit("m/")


@pytest.mark.parametrize(
    ("source", "target", "value", "expected"),
    [
        ("mm", "m", 12.5, 0.0125),
        ("bar", "Pa", 207.0, 2.07e7),
        ("kPa", "Pa", 1.5, 1500.0),
        ("MPa", "bar", 20.7, 207.0),
        ("ms", "s", 250.0, 0.25),
        ("A", "mA", 0.01, 10.0),
        ("degC", "K", 20.0, 293.15),
        ("K", "degC", 293.15, 20.0),
        ("L/min", "m3/s", 60.0, 1e-3),
        ("deg", "rad", 180.0, math.pi),
        ("psi", "Pa", 1.0, 6894.757293168361),
        ("mm/s", "m/s", 3.0, 3e-3),
        ("m^3/s", "m3/s", 2.0, 2.0),  # another spelling: identity
        ("furlong", "furlong", 2.0, 2.0),  # unknown, but the same: identity
    ],
)
def test_conversion(source, target, value, expected):
    change = conversion(source, target)
    assert math.isclose(value * change.scale + change.offset, expected, rel_tol=1e-12)


@pytest.mark.parametrize(
    ("source", "target", "why"),
    [
        ("m", "Pa", "measure different quantities"),
        ("m3/s", "N", "measure different quantities"),
        ("furlong", "m", "unknown unit symbol 'furlong'"),
        ("m/", "m", "unexpected end"),
    ],
)
def test_no_conversion_between_other_quantities(source, target, why):
    with pytest.raises(UnitSyntaxError, match=why):
        conversion(source, target)
