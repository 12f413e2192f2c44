"""The compact envelope (version 3, docs/bus.md#payloads): every decoded type of every
byte-stream format round-trips field for field; sizes against the raw frames; schema checks;
versions 2 and 1 still read."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping

import msgspec
import numpy as np
import pytest

from auvgw.drivers import hn100
from auvgw.drivers.formats import get_format
from auvgw.envelope import (
    ENVELOPE_VERSION,
    SchemaError,
    decode_envelope,
    encode_envelope,
    schema_id,
)
from auvgw.subscribe import typed_message
from auvgw.testing.format_samples import STREAM_FORMATS, samples

T_NS = 1_763_800_000_123_456_789
SEQ = (1_763_800_000 << 32) | 42


def _same(a, b, where: str) -> None:
    """Field for field, arrays with their dtype and shape, NaN where NaN."""
    if dataclasses.is_dataclass(a):
        # the class itself, or one of that name: each load of a DBC builds its classes anew
        assert type(a).__name__ == type(b).__name__, where
        assert type(a) is type(b) or "can_codec" in type(a).__module__, where
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray), where
        assert (a.dtype, a.shape) == (b.dtype, b.shape), where
        assert a.tobytes() == b.tobytes(), where  # bit for bit, NaN included
        assert not b.flags.writeable, where
    elif isinstance(a, float) and math.isnan(a):
        assert isinstance(b, float) and math.isnan(b), where
    elif isinstance(a, tuple | list):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, Mapping):  # (GeoSwathPing: header fields, arrays of columns)
        assert type(a) is type(b) and list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    else:
        assert type(a) is type(b) and a == b, f"{where}: {a!r} != {b!r}"


def _decoded(shared_data):
    for fmt in STREAM_FORMATS:
        f = get_format(fmt)
        for frame in samples(fmt, shared_data):
            for msg in f.decode(frame):
                yield fmt, frame, msg


@pytest.mark.parametrize("decoded", [True, False], ids=["from-codec", "checked"])
def test_every_decoded_type_round_trips_field_for_field(shared_data, decoded):
    types = set()
    for fmt, _frame, msg in _decoded(shared_data):
        payload, enc = encode_envelope(msg, "dev", T_NS, SEQ, wire=fmt, decoded=decoded)
        env = decode_envelope(payload, f"auv/x/sensor/dev/{fmt}")
        name = getattr(msg, "TYPE", type(msg).__name__)
        assert str(enc) == f"application/msgpack;auvgw/{ENVELOPE_VERSION}/{name}"
        assert (env.type, env.device, env.t_recv_ns, env.seq, env.wire) == (
            name, "dev", T_NS, SEQ, fmt,
        )  # fmt: skip
        assert env.schema == schema_id(type(msg))
        _same(msg, env.message, name)
        assert env.message == msg
        # the re-encoded message gives the same bytes: nothing was re-typed on the way
        assert encode_envelope(env.message, "dev", T_NS, SEQ, wire=fmt, decoded=decoded)[0] == (
            payload
        )
        types.add(name)
    # every format contributed (PD0 ensembles, SeaNet packets, Kongsberg XYZ 88 and Depth, ...)
    assert {"pd0.Ensemble", "Hn100Nav", "Ms3aSample", "XYZ88", "Depth", "mtHeadData"} <= types
    assert len(types) >= 20


def test_decoded_messages_fit_in_one_and_a_half_raw_frames(shared_data):
    """The data messages of the five devices: envelope <= 1.5x the frame it came from."""
    worst: dict[str, float] = {}
    for fmt, frame, msg in _decoded(shared_data):
        name = getattr(msg, "TYPE", type(msg).__name__)
        if name not in ("pd0.Ensemble", "Hn100Nav", "Ms3aSample", "XYZ88", "mtHeadData"):
            continue
        if name == "mtHeadData" and len(msg.bins) > msg.data_bytes:
            continue  # 4-bit bins: two per wire byte, one per byte decoded (docs/bus.md)
        payload, _ = encode_envelope(msg, "dvl", T_NS, SEQ, wire=fmt, decoded=True)
        worst[name] = max(worst.get(name, 0.0), len(payload) / len(frame))
    assert set(worst) == {"pd0.Ensemble", "Hn100Nav", "Ms3aSample", "XYZ88", "mtHeadData"}
    assert max(worst.values()) <= 1.5, worst


def _nav(**kw) -> hn100.Hn100Nav:
    status = hn100.CODEC.status_word(aligned=True, gnss_aided=False, dvl_aided=True, error=False)
    base = dict(
        seq=7, status=status, time=10.0, roll=0.01, pitch=-0.02, heading=0.5, rate_x=0.0,
        rate_y=0.0, rate_z=0.1, accel_x=0.01, accel_y=0.0, accel_z=-9.81, vel_n=1.0, vel_e=0.1,
        vel_d=0.0, latitude=0.7, longitude=0.1, depth=20.0,
    )  # fmt: skip
    base.update(kw)
    return hn100.Hn100Nav(**base)


def test_values_off_the_wire_grid_travel_exactly():
    """A message not made by a codec (values no raw integer gives) loses nothing: such values
    travel as floats; NaN of a field without an invalid code too."""
    msg = _nav(roll=0.012345678901234, depth=math.pi, heading=math.nan, vel_n=math.inf)
    env = decode_envelope(encode_envelope(msg, "ins", T_NS, 1)[0])
    _same(msg, env.message, "Hn100Nav")
    wire_msg = hn100.CODEC.decode(hn100.CODEC.encode(_nav()))
    env = decode_envelope(encode_envelope(wire_msg, "ins", T_NS, 1, decoded=True)[0])
    _same(wire_msg, env.message, "Hn100Nav")


def test_a_reader_with_another_table_refuses_the_body():
    msg = hn100.CODEC.decode(hn100.CODEC.encode(_nav()))
    payload, _ = encode_envelope(msg, "ins", T_NS, 1, wire="hn100", decoded=True)
    env = msgspec.msgpack.decode(payload)
    assert env[:3] == [ENVELOPE_VERSION, "Hn100Nav", schema_id(type(msg))]
    env[2] ^= 1
    with pytest.raises(SchemaError, match=r"Hn100Nav: envelope schema .*this reader's table"):
        decode_envelope(msgspec.msgpack.encode(env))
    env[2] ^= 1
    env[7] = env[7][:-1]
    with pytest.raises(SchemaError, match="body has 17 fields, this reader's table 18"):
        decode_envelope(msgspec.msgpack.encode(env))


def test_unknown_types_keep_their_body():
    env = decode_envelope(msgspec.msgpack.encode([3, "NoSuchType", 0x1234, "", "d", 1, 2, [1]]))
    assert (env.message, env.body, env.schema) == (None, [1], 0x1234)
    assert typed_message("NoSuchType", env.body, env.schema) is None
    named, _ = encode_envelope(None, "foo", 5, 6, body={"type": "Foo", "x": 1.5, "a": [1, 2]})
    env = decode_envelope(named)
    assert (env.type, env.body, env.message) == ("Foo", {"x": 1.5, "a": [1, 2]}, None)


def test_versions_two_and_one_are_still_read(shared_data):
    msg = hn100.CODEC.decode(hn100.CODEC.encode(_nav()))
    fields = {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)}
    head = {"v": 2, "type": "Hn100Nav", "wire": "hn100", "device": "ins", "t": T_NS, "seq": 3}
    v2 = msgspec.msgpack.encode({**head, "msg": fields})
    env = decode_envelope(v2)
    assert (env.type, env.wire, env.t_recv_ns, env.seq, env.message) == (
        "Hn100Nav", "hn100", T_NS, 3, None,
    )  # fmt: skip
    assert typed_message(env.type, env.body) == msg
    v1 = json.dumps(
        {"v": 1, "type": "Hn100Nav", "device": "ins", "t_recv_ns": T_NS, "seq": 4, "msg": fields}
    ).encode()
    env = decode_envelope(v1)
    assert (env.type, env.t_recv_ns, env.seq) == ("Hn100Nav", T_NS, 4)
    assert typed_message(env.type, env.body) == msg
    with pytest.raises(ValueError, match="envelope version"):
        decode_envelope(msgspec.msgpack.encode([99, "x"]))


def test_can_samples_round_trip_field_for_field():
    """CAN epochs (DBC message classes, no wire table: floats and ints by their hints)."""
    from auvgw.decoding import pack_can_raw
    from auvgw.testing.can_samples import HN, MAG, hn_sample

    mag = MAG.sample_type(counter=1, bx=21345.6, by=-1234.5, bz=43210.0, status="OK")
    for codec, sample in ((HN, hn_sample(3)), (MAG, mag)):
        frames = codec.encode_sample(sample)
        asm = codec.assembler()
        got = [asm.add(codec.decode_frame(f)) for f in frames][-1]
        payload, _ = encode_envelope(got, "can", T_NS, SEQ, wire="can", decoded=True)
        env = decode_envelope(payload)
        _same(got, env.message, type(got).__name__)
        raw = sum(len(pack_can_raw(f.arbitration_id, f.is_extended_id, f.data)) for f in frames)
        # the header (type, wire, device, two 64-bit stamps) is most of it: an MS3A epoch of
        # two frames (24 raw bytes) cannot fit in 1.5x (docs/bus.md)
        assert len(payload) - raw < 60, (type(got).__name__, len(payload), raw)
        if codec is HN:  # 18 signals of an INS epoch: raw integers, not float64
            assert len(payload) <= 1.5 * raw, (len(payload), raw)


def test_short_arrays_packed_in_python_give_the_numpy_bytes(shared_data, monkeypatch):
    """The gateway's path for short 1-D arrays (packed in Python, envelope.SMALL_ARRAY) gives
    the bytes of the numpy path for every sample of every format and every ensemble of both
    real PD0 files, and for values with NaN, an offset and off the wire grid (half steps:
    rounded half to even both ways)."""
    import auvgw.envelope as envelope
    from auvgw.drivers import pd0
    from auvgw.drivers.spec import WIRE_TYPES, Wire
    from auvgw.envelope import _DECODER, _ENCODER, _wire_coders

    small = envelope.SMALL_ARRAY
    assert small > 0

    def both(fn):
        out = []
        for n in (small, 0):
            monkeypatch.setattr(envelope, "SMALL_ARRAY", n)
            out.append(fn())
        return out

    msgs = [msg for _fmt, _frame, msg in _decoded(shared_data)]
    for name in ("RDI_withBT.000", "vmdas02_os.ENR"):
        frames, _ = get_format("pd0").frames_of_file(shared_data / "pd0" / name)
        msgs += pd0.decode_many([f.data for f in frames])
    assert len(msgs) > 1800
    python, numpy = both(
        lambda: [encode_envelope(m, "d", T_NS, SEQ, decoded=True)[0] for m in msgs]
    )
    assert python == numpy
    for w in (
        Wire("s16", 0, scale=1e-3, invalid=-32768, shape=(6,)),
        Wire("u16", 0, scale=0.5, add=-3.0, shape=(5,)),
        Wire("u8", 0, scale=655.36, shape=(4,)),
        Wire("s16", 0, scale=1e-3, invalid=-32768, shape=(17, 4)),  # a velocity profile
    ):
        enc, dec, _ = _wire_coders(w)
        n = math.prod(w.shape)
        raw = (np.arange(n, dtype=np.dtype(WIRE_TYPES[w.type])) * 3 + 1).reshape(w.shape)
        si = raw * w.scale + w.add
        if w.invalid is not None:
            si.flat[2] = np.nan
        python, numpy = both(lambda si=si, enc=enc: _ENCODER.encode([enc(si, True)]))
        assert python == numpy  # n-D arrays as extension 1, 1-D as bytes
        assert np.array_equal(dec(_DECODER.decode(python)[0]), si, equal_nan=True)
        half = (raw + 0.5) * w.scale + w.add
        python, numpy = both(lambda half=half, enc=enc: _ENCODER.encode([enc(half, True)]))
        assert python == numpy


def test_a_shared_nested_message_is_packed_once_with_the_same_bytes(shared_data):
    """PD0 ensembles of one file share their fixed leader (one immutable message while its
    bytes repeat); its body is packed once and reused, and every envelope is the one a fresh,
    unshared copy gives. A changed (not shared) message is packed anew."""
    import copy

    from auvgw.drivers import pd0

    frames, _ = get_format("pd0").frames_of_file(shared_data / "pd0" / "RDI_withBT.000")
    data = [f.data for f in frames][:40]
    msgs = [pd0.decode(b, verified=True) for b in data]
    assert msgs[0].fixed_leader is msgs[1].fixed_leader  # shared by the codec
    shared = [encode_envelope(m, "d", T_NS, SEQ, decoded=True)[0] for m in msgs]
    fresh = [
        encode_envelope(
            dataclasses.replace(m, fixed_leader=copy.copy(m.fixed_leader)), "d", T_NS, SEQ,
            decoded=True,
        )[0]
        for m in msgs
    ]  # fmt: skip
    assert shared == fresh
    other = dataclasses.replace(msgs[0].fixed_leader, firmware_revision=99)
    env = encode_envelope(dataclasses.replace(msgs[0], fixed_leader=other), "d", T_NS, SEQ,
                          decoded=True)[0]  # fmt: skip
    got = decode_envelope(env).message
    assert got.fixed_leader.firmware_revision == 99
    assert got.variable_leader == msgs[0].variable_leader
