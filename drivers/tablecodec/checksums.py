"""The checksum kinds a frame table can name."""

from __future__ import annotations

import binascii
import zlib
from collections.abc import Callable
from dataclasses import dataclass


def _ubx_fletcher(data: bytes | bytearray | memoryview) -> int:
    a = b = 0
    for byte in data:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return (a << 8) | b


def _xor8(data: bytes | bytearray | memoryview) -> int:
    x = 0
    for byte in data:
        x ^= byte
    return x


@dataclass(frozen=True)
class ChecksumKind:
    """A checksum algorithm: ``compute(covered bytes) -> int`` written in ``size`` bytes.

    ``byte_order`` fixes the order of the written bytes when the algorithm defines it
    (Fletcher: CK_A then CK_B); otherwise the table's byte order applies.
    """

    name: str
    size: int
    compute: Callable[[bytes | bytearray | memoryview], int]
    doc: str
    byte_order: str | None = None


#: checksum kind name -> algorithm
CHECKSUMS: dict[str, ChecksumKind] = {
    k.name: k
    for k in (
        ChecksumKind(
            "crc16-ccitt-false",
            2,
            lambda d: binascii.crc_hqx(d, 0xFFFF),
            "CRC-16, poly 0x1021, init 0xFFFF, no reflection, no final XOR (check 0x29B1)",
        ),
        ChecksumKind(
            "crc16-xmodem",
            2,
            lambda d: binascii.crc_hqx(d, 0),
            "CRC-16, poly 0x1021, init 0x0000, no reflection (XMODEM; check 0x31C3)",
        ),
        ChecksumKind("crc32", 4, zlib.crc32, "CRC-32 (ISO-HDLC/zlib; check 0xCBF43926)"),
        ChecksumKind(
            "ubx-fletcher",
            2,
            _ubx_fletcher,
            "u-blox UBX 8-bit Fletcher: CK_A = sum of bytes, CK_B = sum of CK_A, both mod 256; "
            "written CK_A then CK_B",
            ">",
        ),
        ChecksumKind("xor8", 1, _xor8, "XOR of the bytes (NMEA 0183)"),
        ChecksumKind("sum8", 1, lambda d: sum(d) & 0xFF, "sum of the bytes modulo 256"),
    )
}
