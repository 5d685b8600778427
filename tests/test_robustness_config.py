"""Property tests of the project file (issue 7, section 4).

tests/test_config.py checks one hand-picked mistake per field. Here hypothesis mutates the
reference project ``bench_configs/hydraulic_actuator.toml`` at random: any field replaced by any
TOML value, unknown keys added, fields removed, and the TOML text itself damaged. Every outcome
is a valid project or a :class:`ConfigError` that names a field of the file; never another
exception.
"""

from __future__ import annotations

import copy
import datetime
import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmu_greybox.errors import ConfigError
from fmu_greybox.project.config import load_config, parse_config

REFERENCE = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"
RAW = tomllib.loads(REFERENCE.read_text(encoding="utf-8"))
FUZZ = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)


def field_paths(node: Any, path: str = "") -> list[str]:
    """Dotted paths of every table, entry and list element, e.g. ``stages[1].inputs[0]``."""
    paths = [path] if path else []
    if isinstance(node, dict):
        for key, value in node.items():
            paths += field_paths(value, f"{path}.{key}" if path else key)
    elif isinstance(node, list):
        for i, value in enumerate(node):
            paths += field_paths(value, f"{path}[{i}]")
    return paths


PATHS = field_paths(RAW)


def locate(raw: dict, path: str) -> tuple[Any, str | int]:
    """The container holding ``path`` and the key (or index) of it there."""
    parts: list[str | int] = []
    for piece in path.split("."):
        name, *indices = piece.replace("]", "").split("[")
        parts += [name, *map(int, indices)]
    node: Any = raw
    for part in parts[:-1]:
        node = node[part]
    return node, parts[-1]


def value_at(raw: dict, path: str) -> Any:
    """The value at a dotted path (the whole project for ``""``)."""
    if not path:
        return raw
    container, key = locate(raw, path)
    return container[key]


def toml_type(value: Any) -> type:
    """The TOML type of a value (int and float differ; bool is not an int)."""
    return bool if isinstance(value, bool) else type(value)


scalars = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70),
    st.integers(min_value=-(10**400), max_value=10**400),  # tomllib has no integer limit
    st.floats(),  # nan and inf included
    st.text(max_size=12),
    st.booleans(),
    st.dates(),
    st.datetimes(),
    st.times(),
)
toml_values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3)
    ),
    max_leaves=6,
)


def parse_outcome(raw: dict) -> ConfigError | None:
    """Parse; return the ConfigError (checked to name a field of the file) or None."""
    try:
        parse_config(raw, REFERENCE)
    except ConfigError as error:
        assert type(error) is ConfigError
        assert error.field, str(error)
        assert str(error).startswith(f"{REFERENCE}: {error.field}: "), str(error)
        assert len(str(error)) < 1000
        return error
    return None


@FUZZ
@given(path=st.sampled_from(PATHS), value=toml_values)
def test_any_field_set_to_any_value(path: str, value: Any) -> None:
    raw = copy.deepcopy(RAW)
    container, key = locate(raw, path)
    old = container[key]
    container[key] = value
    error = parse_outcome(raw)
    converted = toml_type(old) is float and toml_type(value) is int  # accepted as a number
    if error is not None and toml_type(value) is not toml_type(old) and not converted:
        # a value of the wrong type is reported at that field (or the table or list holding it)
        assert path.startswith(error.field), (path, error.field, str(error))


@FUZZ
@given(path=st.sampled_from(PATHS))
def test_any_field_removed(path: str) -> None:
    raw = copy.deepcopy(RAW)
    container, key = locate(raw, path)
    del container[key]
    parse_outcome(raw)


ALLOWED = {
    "": {
        "format_version",
        "name",
        "whitebox",
        "recording",
        "signals",
        "stages",
        "gp",
        "split",
        "acceptance",
    },
    "whitebox": {"fmu", "step", "parameters", "fixed_inputs"},
    "recording": {"path", "time_column", "resample"},
    "gp": {
        "inducing",
        "inducing_method",
        "max_iter",
        "target",
        "max_train_samples",
        "seed",
        "kernel",
    },
    "split": {"train_fraction"},
    "acceptance": {
        "max_nrmse",
        "band",
        "max_gain_error_db",
        "max_phase_error_deg",
        "min_coherence",
        "coverage95",
        "coverage68",
        "input",
        "EHV",
        "RAM",
        "ITFV",
    },
    "signals.valve_current": {"role", "unit", "column", "variable"},
    "stages[1]": {
        "name",
        "target",
        "whitebox_output",
        "inputs",
        "feeds_from",
        "lags",
        "target_mode",
        "feed_rates",
    },
}


@FUZZ
@given(
    table=st.sampled_from(list(ALLOWED)),
    key=st.text(min_size=1, max_size=12),
    value=toml_values,
)
def test_unknown_key_is_named_with_the_allowed_ones(table: str, key: str, value: Any) -> None:
    raw = copy.deepcopy(RAW)
    container = value_at(raw, table)
    if key in container or key in ALLOWED[table]:
        return  # not unknown
    container[key] = value
    error = parse_outcome(raw)
    assert error is not None
    assert error.field == (f"{table}.{key}" if table else key)
    assert "unknown field" in str(error) and "allowed here:" in str(error)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("split.train_fraction", 10**400),
        ("whitebox.step", -(10**309)),
        ("recording.resample", 10**309),
    ],
)
def test_integer_too_large_for_a_float_is_a_config_error(field: str, value: int) -> None:
    raw = copy.deepcopy(RAW)
    table, key = field.split(".")
    raw[table][key] = value
    error = parse_outcome(raw)
    assert error is not None and error.field == field
    assert "must be a finite number, not 1000" in str(error) or "not -1000" in str(error)
    assert "..." in str(error)  # the 300-digit number is cut short


lines = REFERENCE.read_text(encoding="utf-8").splitlines(keepends=True)
JUNK = list("[]=\"'.,{}#x1 \\\n")


@FUZZ
@given(data=st.data())
def test_damaged_toml_text(data: st.DataObject, tmp_path_factory: pytest.TempPathFactory) -> None:
    """Delete, duplicate or scribble over lines: a valid project or a ConfigError, nothing else."""
    text = list(lines)
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, len(text) - 1))
        action = data.draw(st.sampled_from(["delete", "duplicate", "scribble"]))
        if action == "delete":
            del text[i]
        elif action == "duplicate":
            text.insert(i, text[i])
        else:
            junk = data.draw(st.text(alphabet=st.sampled_from(JUNK), max_size=6))
            at = data.draw(st.integers(0, len(text[i])))
            text[i] = text[i][:at] + junk + text[i][at:]
        if not text:
            break
    path = tmp_path_factory.mktemp("toml") / "project.toml"
    path.write_text("".join(text), encoding="utf-8")
    try:
        load_config(path)
    except ConfigError as error:
        assert type(error) is ConfigError and str(path) in str(error)


def test_binary_and_non_utf8_files(tmp_path: Path) -> None:
    path = tmp_path / "project.toml"
    path.write_bytes(b"\xff\xfe" + REFERENCE.read_bytes())
    with pytest.raises(ConfigError, match="not UTF-8 text"):
        load_config(path)
    path.write_bytes(b"\x00" * 64)
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_config(path)
    with pytest.raises(ConfigError, match="cannot read the project file"):
        load_config(tmp_path)  # a folder


def test_dates_and_times_are_not_numbers() -> None:
    raw = copy.deepcopy(RAW)
    raw["whitebox"]["step"] = datetime.time(0, 0, 1)
    error = parse_outcome(raw)
    assert error is not None and error.field == "whitebox.step"
    assert "must be a number, not datetime.time(0, 0, 1)" in str(error)
