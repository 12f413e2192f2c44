"""CAN forms of the HN-100 and the MS3A as the tests use them: the shipped DBC codecs
(:data:`HN`, :data:`MAG`) and an INS epoch with every signal set (:func:`hn_sample`); shared by
tests/drivers/test_can_codec.py and tests/service/test_envelope.py."""

from __future__ import annotations

import math

from auvgw.drivers.can_codec import hn100_can, ms3a_can

__all__ = ["HN", "MAG", "hn_sample"]

HN = hn100_can()
MAG = ms3a_can()


def hn_sample(seq: int, k: float = 1.0):
    """An HN-100 CAN epoch, sequence ``seq``, every value scaled by ``k``."""
    sample_type = HN.sample_type
    assert sample_type is not None  # built when the DBC was read
    return sample_type(
        seq=seq,
        time=1234.567891 * k,
        roll=0.1 * k,
        pitch=-0.2 * k,
        heading=3.0 * k,
        rate_x=0.01 * k,
        rate_y=0.02 * k,
        rate_z=-0.03 * k,
        accel_x=0.1 * k,
        accel_y=0.2 * k,
        accel_z=-9.81 * k,
        vel_n=1.0 * k,
        vel_e=-0.5 * k,
        vel_d=0.01 * k,
        latitude=math.radians(43.1234567) * k,
        depth=100.5 * k,
        longitude=math.radians(-5.9876543) * k,
        alignment="FINE",
        gnss_aided=0,
        dvl_aided=1,
        error="OK",
        reserved=0,
    )
