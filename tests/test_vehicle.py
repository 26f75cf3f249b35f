"""Vehicle parameters: TOML round trip, shipped files, and every way a vehicle file can be wrong."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from smcpilot.errors import ConfigError, VehicleFileError
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TOML = ROOT / "smcpilot" / "data" / "default-vehicle.toml"
EXAMPLE_TOMLS = sorted((ROOT / "examples" / "vehicles").glob("*.toml"))

NUMERIC_FIELDS = [f.name for f in dataclasses.fields(VehicleParams) if f.name != "name"]


def _write(tmp_path: Path, text: str, name: str = "v.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# -- round trip ---------------------------------------------------------------------------------


def test_default_round_trip(tmp_path):
    p = _write(tmp_path, DEFAULT_VEHICLE.to_toml())
    assert VehicleParams.from_toml(p) == DEFAULT_VEHICLE


_positive = st.floats(min_value=1e-9, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=40, deadline=None)
@given(
    mass=_positive,
    izz=_positive,
    jr=st.floats(min_value=0.0, max_value=1.0),
    idle=st.floats(min_value=0.0, max_value=100.0),
    extra=st.floats(min_value=1e-6, max_value=1e4),
    name=st.text(alphabet="abcdefghijklmnopqrstuvwxyz-_0123456789 ", min_size=1, max_size=20),
)
def test_random_round_trip(tmp_path_factory, mass, izz, jr, idle, extra, name):
    """to_toml -> from_toml gives an equal object, floats bit for bit (repr round-trips)."""
    v = VehicleParams(
        name=name,
        mass_kg=mass,
        izz_kg_m2=izz,
        rotor_inertia_kg_m2=jr,
        rotor_speed_idle_radps=idle,
        rotor_speed_max_radps=idle + extra,
    )
    p = tmp_path_factory.mktemp("rt") / "v.toml"
    p.write_text(v.to_toml(), encoding="utf-8")
    back = VehicleParams.from_toml(p)
    assert back == v
    assert back.to_toml() == v.to_toml()


def test_integer_values_are_accepted(tmp_path):
    p = _write(tmp_path, "[vehicle]\nmass_kg = 2\n")
    v = VehicleParams.from_toml(p)
    assert v.mass_kg == 2.0
    assert v.arm_length_m == DEFAULT_VEHICLE.arm_length_m  # left-out keys take the default


# -- shipped files ------------------------------------------------------------------------------


def test_shipped_default_equals_dataclass_defaults():
    assert DEFAULT_TOML.is_file()
    assert VehicleParams.from_toml(DEFAULT_TOML) == VehicleParams()


def test_shipped_default_lists_every_key():
    """The shipped file spells out every field (so it documents the full set), none defaulted."""
    import tomllib

    table = tomllib.loads(DEFAULT_TOML.read_text(encoding="utf-8"))["vehicle"]
    assert set(table) == {f.name for f in dataclasses.fields(VehicleParams)}


def test_examples_exist():
    assert EXAMPLE_TOMLS, "examples/vehicles/*.toml should ship at least one vehicle"


@pytest.mark.parametrize("path", EXAMPLE_TOMLS, ids=lambda p: p.name)
def test_example_vehicles_load(path):
    v = VehicleParams.from_toml(path)
    assert v != DEFAULT_VEHICLE
    assert v.name != DEFAULT_VEHICLE.name
    # thrust/weight of a flyable vehicle is above 1
    assert v.thrust_to_weight > 1.0


# -- errors -------------------------------------------------------------------------------------


def test_unknown_key_names_the_key(tmp_path):
    p = _write(tmp_path, "[vehicle]\nmass_kg = 1.0\nwingspan_m = 2.0\n")
    with pytest.raises(VehicleFileError, match="wingspan_m"):
        VehicleParams.from_toml(p)


def test_misspelt_key_names_the_key(tmp_path):
    p = _write(tmp_path, "[vehicle]\nmass = 1.0\n")
    with pytest.raises(VehicleFileError, match="'mass'"):
        VehicleParams.from_toml(p)


@pytest.mark.parametrize("key", ["mass_kg", "izz_kg_m2", "rotor_speed_max_radps"])
def test_non_number_names_the_key(tmp_path, key):
    p = _write(tmp_path, f'[vehicle]\n{key} = "heavy"\n')
    with pytest.raises(VehicleFileError, match=key):
        VehicleParams.from_toml(p)


def test_boolean_is_not_a_number(tmp_path):
    p = _write(tmp_path, "[vehicle]\nmass_kg = true\n")
    with pytest.raises(VehicleFileError, match="mass_kg"):
        VehicleParams.from_toml(p)


@pytest.mark.parametrize("key", NUMERIC_FIELDS)
def test_negative_names_the_key(tmp_path, key):
    p = _write(tmp_path, f"[vehicle]\n{key} = -1.0\n")
    with pytest.raises(VehicleFileError, match=key):
        VehicleParams.from_toml(p)


@pytest.mark.parametrize("key", ["mass_kg", "thrust_coeff_n_s2", "ixx_kg_m2"])
def test_zero_where_positive_required(tmp_path, key):
    p = _write(tmp_path, f"[vehicle]\n{key} = 0.0\n")
    with pytest.raises(VehicleFileError, match=key):
        VehicleParams.from_toml(p)


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_non_finite_names_the_key(tmp_path, value):
    p = _write(tmp_path, f"[vehicle]\narm_length_m = {value}\n")
    with pytest.raises(VehicleFileError, match="arm_length_m"):
        VehicleParams.from_toml(p)


def test_idle_above_max_is_rejected(tmp_path):
    p = _write(tmp_path, "[vehicle]\nrotor_speed_idle_radps = 300.0\nrotor_speed_max_radps = 200.0\n")
    with pytest.raises(VehicleFileError, match="rotor_speed_idle_radps"):
        VehicleParams.from_toml(p)


def test_missing_vehicle_table(tmp_path):
    p = _write(tmp_path, "mass_kg = 1.0\n")
    with pytest.raises(VehicleFileError, match=r"missing \[vehicle\] table"):
        VehicleParams.from_toml(p)


def test_wrong_table_name(tmp_path):
    p = _write(tmp_path, "[vehicles]\nmass_kg = 1.0\n")
    with pytest.raises(VehicleFileError, match=r"\[vehicle\]"):
        VehicleParams.from_toml(p)


def test_extra_top_level_table_is_named(tmp_path):
    p = _write(tmp_path, "[vehicle]\nmass_kg = 1.0\n[motors]\nn = 4\n")
    with pytest.raises(VehicleFileError, match="motors"):
        VehicleParams.from_toml(p)


def test_invalid_toml(tmp_path):
    p = _write(tmp_path, "[vehicle\nmass_kg = = 1\n")
    with pytest.raises(VehicleFileError, match="not valid TOML"):
        VehicleParams.from_toml(p)


def test_missing_file(tmp_path):
    p = tmp_path / "nope.toml"
    with pytest.raises(VehicleFileError, match="cannot read"):
        VehicleParams.from_toml(p)


def test_error_message_names_the_file(tmp_path):
    p = _write(tmp_path, "[vehicle]\nmass_kg = -1\n", name="my-quad.toml")
    with pytest.raises(VehicleFileError, match="my-quad.toml"):
        VehicleParams.from_toml(p)


def test_vehicle_file_error_is_a_config_error():
    """The CLI turns ConfigError into exit 2; a vehicle error must be one."""
    assert issubclass(VehicleFileError, ConfigError)


def test_empty_name_rejected():
    with pytest.raises(VehicleFileError, match="name"):
        VehicleParams(name="")


@pytest.mark.parametrize("name", ['my "quad"', "C:\\quads\\x", "two\nlines"], ids=["quote", "backslash", "newline"])
def test_round_trip_names_needing_escapes(tmp_path, name):
    v = VehicleParams(name=name)
    p = _write(tmp_path, v.to_toml())
    assert VehicleParams.from_toml(p) == v


def test_vehicle_files_with_the_old_rad_s_key_names_still_load(tmp_path) -> None:
    from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

    path = tmp_path / "old.toml"
    path.write_text("[vehicle]\nrotor_speed_max_rad_s = 1000.0\nrotor_speed_idle_rad_s = 100.0\n")
    v = VehicleParams.from_toml(path)
    assert (v.rotor_speed_max_radps, v.rotor_speed_idle_radps) == (1000.0, 100.0)
    assert v.mass_kg == DEFAULT_VEHICLE.mass_kg
    path.write_text("[vehicle]\nrotor_speed_max_rad_s = 1000.0\nrotor_speed_max_radps = 900.0\n")
    import pytest

    from smcpilot.errors import VehicleFileError

    with pytest.raises(VehicleFileError, match="rotor_speed_max_rad_s.*old name"):
        VehicleParams.from_toml(path)
