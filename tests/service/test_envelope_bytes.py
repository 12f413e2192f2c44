"""The envelope read straight from a frame's bytes (the gateway's hot path:
``DeviceDecoder.envelope_body``, ``auvgw.envelope.layout_body``) is byte for byte the envelope
of the decoded message, whichever way that one is packed (trusted or checked): on every
ensemble of both real PD0 files, emulated ensembles (bottom lock lost, every coordinate frame,
high-resolution blocks), HN-100 frames with any field values, and a site's HN-100 table. A
frame the decode refuses gets none, so the gateway publishes only what decode accepts and
reports the decode's error as before."""

from __future__ import annotations

import random
import struct

import numpy as np
import pytest

from auvgw.decoding import DeviceDecoder
from auvgw.drivers import hn100, pd0
from auvgw.drivers.formats import format_from_table, get_format
from auvgw.envelope import decode_envelope, encode_envelope, pack_envelope
from auvgw.ground.paths import config_file
from auvgw.testing.dvl import offline, scenario
from auvgw.testing.format_samples import hn100_frames

T_NS = 1_763_800_000_123_456_789
SEQ = (1_763_800_000 << 32) | 42


def _from_bytes(dec: DeviceDecoder, frame: bytes) -> bytes | None:
    got = dec.envelope_body(frame)
    if got is None:
        return None
    type_name, schema, body = got
    return pack_envelope(type_name, schema, dec.format.name, "dev", T_NS, SEQ, body)


def _check(dec: DeviceDecoder, frame: bytes) -> bytes:
    """The envelope from the bytes equals the decoded message's, trusted and checked."""
    fast = _from_bytes(dec, frame)
    (msg,) = dec.decode_raw(frame, verified=True)
    wire = dec.format.name
    assert fast is not None
    assert fast == encode_envelope(msg, "dev", T_NS, SEQ, wire=wire, decoded=True)[0]
    assert fast == encode_envelope(msg, "dev", T_NS, SEQ, wire=wire)[0]
    return fast


@pytest.mark.parametrize("name", ["RDI_withBT.000", "vmdas02_os.ENR"])
def test_every_real_pd0_ensemble(shared_data, name):
    fmt = get_format("pd0")
    dec = DeviceDecoder("dvl", fmt)
    frames, _ = fmt.frames_of_file(shared_data / "pd0" / name)
    n = 0
    for f in frames:
        fast = _check(dec, f.data)
        if n % 200 == 0:  # and a reader gets the decoded message back
            assert decode_envelope(fast).message == pd0.decode(f.data)
        n += 1
    assert n >= 690


@pytest.mark.parametrize(
    "options",
    [
        {"frame": "beam"},
        {"frame": "earth", "bt_high_res": True, "bt_range": True},
        {"frame": "instrument", "water_mass": True, "cells": 12},
        {"cells": 40, "bt_high_res": True},  # a profile of 160 values: numpy's path
    ],
)
def test_emulated_pd0_ensembles(tmp_path, options):
    """The emulated Pathfinder (its 77-byte variable leader, 0x5803 and 0x5804 blocks, water
    cells), through a run where bottom lock comes and goes."""
    em, _, _ = offline(scenario({"options": options}), tmp_path)
    dec = DeviceDecoder("dvl", get_format("pd0"))
    ids = set()
    for t in np.arange(0.0, 120.0, 1.3):
        frame = em.frame_at(float(t))
        _check(dec, frame)
        ids.update(pd0.decode(frame).ids)
    assert {pd0.ID_FIXED_LEADER, pd0.ID_VARIABLE_LEADER, pd0.ID_BOTTOM_TRACK} <= ids
    assert options.get("cells", 0) == 0 or pd0.ID_VELOCITY in ids
    assert not options.get("bt_high_res") or pd0.ID_BT_HIGH_RES in ids


def _resealed_hn100(body: bytes, spec) -> bytes:
    """An HN-100 frame with the given field bytes: sync, length and checksum made good."""
    frame = bytearray(hn100_frames(1)[0])
    frame[4 : spec.checksum_offset] = body
    cs = spec.checksum.compute(bytes(frame[spec.checksum_start : spec.checksum_offset]))
    order = "little" if spec.checksum_byte_order == "<" else "big"
    frame[spec.checksum_offset :] = cs.to_bytes(spec.checksum.size, order)
    return bytes(frame)


def test_hn100_frames_with_any_values():
    """Every field value the wire can carry (random bytes, the limits of each type, the
    status bits in every combination) gives the decoded message's envelope."""
    codec = hn100.default_codec()
    spec = codec.spec
    dec = DeviceDecoder("ins", get_format("hn100"))
    rng = random.Random(16)
    n = spec.checksum_offset - 4
    bodies = [bytes(rng.getrandbits(8) for _ in range(n)) for _ in range(300)]
    bodies += [bytes([b]) * n for b in (0x00, 0x7F, 0x80, 0xFF)]
    frames = [*hn100_frames(20), *(_resealed_hn100(b, spec) for b in bodies)]
    for frame in frames:
        assert codec.framer().feed(frame)[0].data == frame  # a frame its framer delivers
        _check(dec, frame)


def test_a_site_hn100_table_gets_its_own_reader(tmp_path):
    """A site table (roll as an IEEE float, so NaN and infinities too) reads its own layout."""
    text = config_file("hn100.toml").read_text()
    shipped = 'name = "roll"\ntype = "s32"\noffset = 12\nscale = 1e-6\n'
    assert shipped in text
    path = tmp_path / "site.toml"
    path.write_text(text.replace(shipped, 'name = "roll"\ntype = "f32"\noffset = 12\n'))
    dec = DeviceDecoder("ins", format_from_table("hn100", path))
    spec = hn100.Hn100Codec.from_toml(path).spec
    rng = random.Random(7)
    n = spec.checksum_offset - 4
    bodies = [bytes(rng.getrandbits(8) for _ in range(n)) for _ in range(200)]
    bodies += [bytes(8) + struct.pack("<f", v) + bytes(n - 12) for v in (np.nan, np.inf, 0.1)]
    for body in bodies:
        _check(dec, _resealed_hn100(body, spec))


def _reseal_pd0(frame: bytearray) -> bytes:
    nbytes = frame[2] | frame[3] << 8
    if nbytes + 2 <= len(frame):
        struct.pack_into("<H", frame, nbytes, pd0.checksum(frame[:nbytes]))
    return bytes(frame)


def test_a_frame_the_decode_refuses_gets_no_envelope_from_its_bytes(shared_data):
    """PD0 frames with a good checksum and a corrupted layout (data type count, offsets,
    data type IDs, cell and beam counts, length): wherever the decode raises, no envelope is
    read from the bytes (the gateway decodes, and reports the decode's error); wherever it
    decodes, the envelope from the bytes is the decoded one."""
    fmt = get_format("pd0")
    dec = DeviceDecoder("dvl", fmt)
    rng = random.Random(2016)
    refused = accepted = 0
    sources = [*(f.data for f, _ in zip(fmt.frames_of_file(
        shared_data / "pd0" / "vmdas02_os.ENR")[0], range(3), strict=False))]  # fmt: skip
    sources += [f.data for f, _ in zip(fmt.frames_of_file(
        shared_data / "pd0" / "RDI_withBT.000")[0], range(3), strict=False)]  # fmt: skip
    for i in range(1500):
        frame = bytearray(rng.choice(sources))
        ntypes = frame[5]
        offsets = struct.unpack_from(f"<{ntypes}H", frame, 6)
        where = rng.choice(["ntypes", "offset", "id", "counts", "nbytes"])
        if where == "ntypes":
            frame[5] = rng.randrange(1, ntypes + 3)
        elif where == "offset":
            k = rng.randrange(ntypes)
            struct.pack_into("<H", frame, 6 + 2 * k, max(0, offsets[k] + rng.randrange(-90, 90)))
        elif where == "id":
            o = rng.choice(offsets)
            frame[o : o + 2] = rng.choice([b"\x00\x00", b"\x80\x00", b"\x00\x01", b"\x00\x06",
                                           b"\x03\x58", b"\x04\x58", b"\x99\x99"])  # fmt: skip
        elif where == "counts":
            fl = offsets[0]
            frame[fl + 8 + rng.randrange(2)] = rng.randrange(0, 80)
        else:
            cut = rng.randrange(-40, 0)
            frame = frame[:cut] if rng.random() < 0.5 else frame + bytes(-cut)
            struct.pack_into("<H", frame, 2, len(frame) - 2)
        data = _reseal_pd0(frame)
        try:
            (msg,) = dec.decode_raw(data, verified=True)
        except Exception:
            assert dec.envelope_body(data) is None, (i, where)
            assert dec.item(data, 0, True).error  # the gateway's error for it
            refused += 1
            continue
        fast = _from_bytes(dec, data)
        assert fast == encode_envelope(msg, "dev", T_NS, SEQ, wire="pd0", decoded=True)[0]
        accepted += 1
    assert refused > 200 and accepted > 200
