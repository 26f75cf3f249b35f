"""Parameter metadata people and ground stations can read: the shipped ``apm.pdef.xml`` is
current with the parameter table, parses with MAVProxy's own loader code path (lxml.objectify,
as ``param help`` walks it; MAVProxy itself is not a dependency), and the ground client's reader
(xml.etree, same schema) agrees with the table."""

from __future__ import annotations

from fc.param_meta import MARKDOWN_PATH, PDEF_PATH, main, parameters_markdown, pdef_xml
from fc.params import PARAMS, defaults_table
from ground.vehicle.param_meta import load_param_meta, param_meta
from smcpilot.faults import SIM_PARAMS


def test_shipped_files_are_current() -> None:
    assert main(["--check"]) == 0, "run: python -m fc.param_meta"
    assert PDEF_PATH.read_text(encoding="utf-8") == pdef_xml()
    assert MARKDOWN_PATH.read_text(encoding="utf-8") == parameters_markdown()


def _mavproxy_help_tree(path):
    """MAVProxy's ``ParamState.param_help_tree`` (mavproxy_param.py), step by step."""
    xml = open(path).read()  # noqa: SIM115 - as MAVProxy reads it: text, not bytes
    from lxml import objectify

    objectify.enable_recursive_str()
    tree = objectify.fromstring(xml)
    htree = {}
    for p in tree.vehicles.parameters.param:
        n = p.get("name").split(":")[1]
        htree[n] = p
    for lib in tree.libraries.parameters:
        for p in lib.param:
            n = p.get("name")
            htree[n] = p
    return htree


def test_mavproxy_loader_reads_every_parameter_with_units_ranges_and_values() -> None:
    htree = _mavproxy_help_tree(PDEF_PATH)
    assert set(htree) == {p.name for p in PARAMS} | {p.name for p in SIM_PARAMS}
    for row in defaults_table():
        h = htree[row["name"]]
        assert h.get("humanName") and h.get("documentation")
        fields = {f.get("name"): str(f) for f in h.field}  # as `param help` prints them
        lo, hi = (float(x) for x in fields["Range"].split())
        assert (lo, hi) == (row["min"], row["max"]), row["name"]
        assert fields.get("Units", "") == row["unit"], row["name"]
        assert ("RebootRequired" in fields) == row["restart"], row["name"]
    # `param help` lists the values of the first child
    values = htree["FS_GCS_ENABLE"].getchildren()[0].getchildren()
    assert [(v.get("code"), str(v)) for v in values] == [("0", "off"), ("1", "RTL"), ("2", "LAND")]
    assert "Default 300 m" in htree["FENCE_RADIUS"].get("documentation")


def test_ground_reader_agrees_with_the_table() -> None:
    meta = param_meta()
    assert meta == load_param_meta(PDEF_PATH)
    for row in defaults_table():
        m = meta[row["name"]]
        assert (m.lo, m.hi, m.unit, m.restart) == (row["min"], row["max"], row["unit"], row["restart"])
        assert m.description.startswith(str(row["description"]))
    assert meta["FC_CONTROLLER"].values == {0: "adaptive_pid_smc", 1: "pid_smc", 2: "cascade_pid", 3: "sign_smc", 4: "se3_geometric", 5: "indi"}
    assert meta["DOB_MODE"].values == {-1: "auto", 0: "none", 1: "sigma", 2: "lumped", 3: "input"}
    assert meta["ARMING_CHECK"].values == {0: "Disabled", 1: "Enabled"}
    assert meta["SIM_GYR_FAULT"].lo == 0.0
