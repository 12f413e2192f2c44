"""Hostile bus payloads for tests and benchmarks (issue 27): envelopes of every version with
fields at the edges of their types, wrong types, deep nesting, huge sizes, raw bytes.

:func:`hostile_payloads` is a Hypothesis strategy (``tests/service/test_hostile_inputs.py``
draws from it, ``benchmarks/bench_hostile.py`` sweeps thousands of its examples)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import msgspec
from hypothesis import strategies as st

from auvgw.envelope import ENVELOPE_VERSION

__all__ = ["EDGES", "fusion_traffic", "hostile_payloads"]

#: numbers at the edges of the types an envelope carries, and the wrong types for them
EDGES = st.one_of(
    st.sampled_from([0, -1, 1, 2**31, 2**32, 2**53 + 1, 2**63 - 1, 2**63, 2**64 - 1, 2**64,
                     -(2**63), -(2**63) - 1, 10**30]),
    st.sampled_from([0.0, -0.0, 1e300, -1e300, float("inf"), float("-inf"), float("nan"), 5e-324]),
    st.booleans(), st.none(), st.text(max_size=8), st.just("x" * 70_000), st.binary(max_size=8),
    st.lists(st.integers(), max_size=3), st.dictionaries(st.text(max_size=3), st.integers(),
                                                         max_size=2),
)  # fmt: skip


def _json_safe(v):
    if isinstance(v, float) and v != v:
        return "NaN"
    if isinstance(v, bytes):
        return v.hex()
    return v


@st.composite
def hostile_payloads(draw) -> bytes:
    """One hostile payload: an envelope of each version with one or more fields at an edge, a
    body nested deep, a huge one, or raw bytes."""
    kind = draw(st.sampled_from(["v1", "v2", "v3", "deep_json", "deep_msgpack", "raw", "huge"]))
    if kind == "raw":
        return draw(st.binary(max_size=64))
    if kind == "huge":
        return b"\x93" + b"\xda\xff\xff" + b"a" * 65_535  # a 3-array of one 64 kB string
    if kind == "deep_json":
        n = draw(st.integers(33, 30_000))
        return b'{"v": 1, "msg": ' + b"[" * n + b"]" * n + b"}"
    if kind == "deep_msgpack":
        n = draw(st.integers(33, 30_000))
        return b"\x98\x03" + b"\x91" * n + b"\xc0"
    fields = {"type": "pd0.Ensemble", "device": "dvl", "t": 1_780_000_102 * 10**9, "seq": 7,
              "wire": "pd0", "schema": 0, "msg": {}}  # fmt: skip
    for name in draw(st.lists(st.sampled_from(list(fields)), min_size=1, max_size=3)):
        fields[name] = draw(EDGES)
    if kind == "v1":
        doc = {"v": 1, "type": fields["type"], "device": fields["device"],
               "t_recv_ns": fields["t"], "seq": fields["seq"], "msg": fields["msg"]}
        return json.dumps({k: _json_safe(v) for k, v in doc.items()}).encode()
    enc = msgspec.msgpack.Encoder()
    try:
        if kind == "v2":
            return enc.encode({"v": 2, **fields})
        return enc.encode([ENVELOPE_VERSION, fields["type"], fields["schema"], fields["wire"],
                           fields["device"], fields["t"], fields["seq"], fields["msg"]])
    except (OverflowError, TypeError, msgspec.EncodeError):  # beyond what MessagePack holds
        return enc.encode([ENVELOPE_VERSION, "pd0.Ensemble", 0, "", "dvl", -1, 0, []])


def fusion_traffic(
    tmp: Path, seconds: float = 4.0, t0: float = 100.0, vehicle: str = "auv1"
) -> tuple[list[tuple[float, str, bytes]], Any]:
    """Good traffic: ``seconds`` of the emulated survey's INS and DVL from vehicle time ``t0``
    as gateway envelopes, host-time ordered ``(t s, key, payload)``, and the fusion settings
    that fit them (``tmp``: a folder for the emulated ports)."""
    from auvgw.bus import Keys, encode_envelope
    from auvgw.decoding import message_kind
    from auvgw.stages.fusion import FusionStageConfig
    from auvgw.testing.fusion_emulated import (
        decode_serial,
        dvl_stream,
        emulate,
        filter_config,
        ins_output,
        survey_scenario,
    )

    keys = Keys(vehicle)
    em = emulate(survey_scenario(t0 + seconds + 1.0), tmp)
    ins = ins_output(em, t0, t0 + seconds)
    dvl = dvl_stream(em, t0, t0 + seconds)
    msgs = decode_serial(ins.serial, "hn100", "ins") + decode_serial(dvl, "pd0", "dvl")
    msgs.sort(key=lambda m: m[0])
    cfg = FusionStageConfig(vehicle=vehicle, ins_device="ins", filter=filter_config(em, t0),
                            latency_s={"ins": ins.serial.frame_latency_s,
                                       "dvl": dvl.frame_latency_s})  # fmt: skip
    out = []
    for seq, (t, device, msg) in enumerate(msgs):
        payload, _ = encode_envelope(msg, device, round(t * 1e9), seq)
        out.append((t, keys.sensor(device, message_kind(msg)), payload))
    return out, cfg
