"""STATUSTEXT longer than 50 characters: MAVLink 2 chunks (``id``, ``chunk_seq``) from the FC,
joined again by the ground client, through pymavlink's own encoder and parser."""

from __future__ import annotations

import random

from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.telemetry import statustexts
from ground.vehicle.telemetry import StatusTextAssembler

printable = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=400)


def _wire(msgs: list[mavlink.MAVLink_message], mav: mavlink.MAVLink) -> list[mavlink.MAVLink_message]:
    """Pack as the FC sends, parse as a ground station receives."""
    rx = mavlink.MAVLink(None)
    out = []
    for m in msgs:
        got = rx.parse_buffer(m.pack(mav))
        assert got is not None and len(got) == 1
        out.append(got[0])
    return out


@given(text=printable)
def test_any_text_arrives_whole(text: str) -> None:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msgs = statustexts(mav, mavlink.MAV_SEVERITY_WARNING, text)
    if len(text) <= 50:
        assert len(msgs) == 1 and msgs[0].id == 0
    else:
        assert len({m.id for m in msgs}) == 1 and msgs[0].id != 0
        assert [m.chunk_seq for m in msgs] == list(range(len(msgs)))
    asm = StatusTextAssembler()
    delivered = [d for m in _wire(msgs, mav) for d in asm.feed(m)]
    assert len(delivered) == 1
    assert delivered[0].text == text and delivered[0].severity == mavlink.MAV_SEVERITY_WARNING


def test_interleaved_texts_from_two_sources_and_a_lost_chunk() -> None:
    a = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    b = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    ta = "Takeoff refused: altitude 1000 m is above fence FENCE_ALT_MAX 100 m"
    tb = "B" * 120
    ma, mb = _wire(statustexts(a, 4, ta), a), _wire(statustexts(b, 4, tb), b)
    assert ma[0].id == mb[0].id == 1  # the same id from two vehicles: kept apart by source
    asm = StatusTextAssembler()
    order = [ma[0], mb[0], mb[1], ma[1], mb[2]]
    got = [d.text for m in order for d in asm.feed(m)]
    assert got == [ta, tb]
    # a lost middle chunk leaves a visible gap, never a silently shorter text
    lost = _wire(statustexts(a, 4, "x" * 50 + "y" * 50 + "end"), a)
    assert [d.text for m in (lost[0], lost[2]) for d in asm.feed(m)] == ["x" * 50 + "[...]" + "end"]


def test_a_text_whose_end_never_comes_is_delivered_after_the_timeout() -> None:
    now = [0.0]
    asm = StatusTextAssembler(timeout_s=2.0, clock_s=lambda: now[0])
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msgs = _wire(statustexts(mav, 4, "z" * 120), mav)
    assert asm.feed(msgs[0]) == [] and asm.feed(msgs[1]) == []
    now[0] = 3.0
    single = _wire(statustexts(mav, 6, "Armed"), mav)[0]
    assert [m.text for m in asm.feed(single)] == ["z" * 100, "Armed"]


def test_the_chunk_id_counts_per_encoder_so_logs_stay_reproducible() -> None:
    rng = random.Random(3)
    texts = ["".join(rng.choice("abc ") for _ in range(rng.randint(51, 200))) for _ in range(5)]
    runs = []
    for _ in range(2):
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        runs.append([bytes(m.pack(mav)) for t in texts for m in statustexts(mav, 4, t)])
    assert runs[0] == runs[1]


def test_the_log_reader_joins_chunks(tmp_path) -> None:
    from ground.logs.load import load_log
    from smcpilot.tlog import TlogWriter

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    long_text = "Set-point refused: 1e+06 m from home is outside fence FENCE_RADIUS 300 m"
    path = tmp_path / "t.tlog"
    with TlogWriter(path) as w:
        w.write(1_000_000, mav.heartbeat_encode(2, 3, 0, 0, 0).pack(mav))
        for m in statustexts(mav, mavlink.MAV_SEVERITY_WARNING, long_text) + statustexts(mav, 6, "Armed"):
            w.write(2_000_000, m.pack(mav))
    assert [e.text for e in load_log(path).events] == [long_text, "Armed"]
