"""A bundle's parts as netem passes them on (netem.bundle_parts): each message kept as the JSON
string it came in where that is the string orjson writes of it, else read by the model: the
packets netem makes of them are the same bytes either way, and a malformed bundle is counted."""

from __future__ import annotations

import orjson
import pytest
from hypothesis import given
from hypothesis import strategies as st

from formation.codec import Malformed
from netem.bundle_parts import read_bundle
from netem.proxy.records import ONE_COPY, Escaped, message_json, packet_json_of

HEAD = {"run_id": "r", "sender": "pool/1", "seq": 0, "epoch": 3, "stamp_ns": 1}


def _bundle(messages: list[str]) -> bytes:
    parts = [{"agent": i + 1, "seq": 3, "message": m} for i, m in enumerate(messages)]
    return orjson.dumps({**HEAD, "kind": "bundle", "phase": "state", "parts": parts})


def _packets(payloads: list[Escaped] | list[bytes]) -> list[bytes]:
    return [packet_json_of(1, 3, 3, 1, message_json(p)) for p in payloads]


@given(st.lists(st.text(), min_size=1, max_size=4))
def test_a_part_is_passed_on_as_the_packet_its_message_alone_makes(messages: list[str]) -> None:
    malformed = Malformed()
    got = read_bundle(malformed, "k", _bundle(messages))
    assert got is not None and not malformed.counts
    _, payloads = got
    alone = [m.encode(errors="surrogatepass") for m in messages]
    assert _packets(payloads) == _packets(alone)
    for p, m in zip(payloads, alone, strict=True):
        assert (p.to_bytes() if type(p) is Escaped else p) == m


@pytest.mark.parametrize(
    ("written", "escaped"),
    [
        (b'"{\\"a\\":1}"', True),  # as orjson writes it: kept as it came
        (b'"\\u0041"', False),  # orjson writes "A": read by the model
        (b'"a\\/b"', False),  # orjson writes "/" as itself
        (b'"\\\\n"', False),  # a backslash of its own: not only \" escapes
        ('"é"'.encode(), True),  # UTF-8 as itself
    ],
)
def test_a_message_is_kept_as_it_came_only_where_orjson_writes_it_so(
    written: bytes, escaped: bool
) -> None:
    payload = _bundle(["PART"]).replace(b'"PART"', written)
    got = read_bundle(Malformed(), "k", payload)
    assert got is not None
    _, (p,) = got
    assert (type(p) is Escaped) == escaped
    text: str = orjson.loads(written)
    assert _packets([p]) == _packets([text.encode()])


@pytest.mark.parametrize(
    "written",
    [b"12", b"{}", b'"\xff"', b'"a', b'"\\x"'],
    ids=["number", "object", "not UTF-8", "cut", "escape"],
)
def test_a_bundle_with_a_malformed_message_is_counted(written: bytes) -> None:
    malformed = Malformed()
    assert read_bundle(malformed, "k", _bundle(["PART"]).replace(b'"PART"', written)) is None
    assert malformed.counts == {"k": 1}


def test_one_copy_is_the_packet_of_one_copy() -> None:
    assert packet_json_of(4, 5, 6, 1, b'"m"') == ONE_COPY % (4, 5, 6, b'"m"')
