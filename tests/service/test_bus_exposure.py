"""Security that cannot be half on (issue 27, item 5): ``[bus.tls]`` with no TLS endpoint is
refused at load; a bus without TLS or authentication that another machine could reach makes
every process say so at start-up (one warning naming the endpoints)."""

from __future__ import annotations

import logging

import pytest
from pydantic import ValidationError

from auvgw.bus import open_session
from auvgw.config.bus import BusConfig
from auvgw.ground.procs import free_port

TLS = {"root_ca_certificate": "ca.pem", "listen_certificate": "c.pem",
       "listen_private_key": "k.pem"}  # fmt: skip


def test_tls_without_a_tls_endpoint_is_refused():
    with pytest.raises(ValidationError, match=r"no listen/connect endpoint uses tls/"):
        BusConfig(tls=TLS, listen=["tcp/127.0.0.1:7447"])
    with pytest.raises(ValidationError, match=r"no listen/connect endpoint uses tls/"):
        BusConfig(tls=TLS)  # the default endpoint would be plain TCP
    assert BusConfig(tls=TLS, listen=["tls/127.0.0.1:7447"]).tls is not None


@pytest.mark.parametrize(("endpoints", "open_to"), [
    (["tcp/127.0.0.1:7447"], []),
    (["tcp/[::1]:7447", "tcp/localhost:7448"], []),
    (["tcp/0.0.0.0:7447"], ["tcp/0.0.0.0:7447"]),
    (["tcp/[::]:7447", "tcp/127.0.0.1:1"], ["tcp/[::]:7447"]),
    (["tcp/192.168.1.10:7447"], ["tcp/192.168.1.10:7447"]),
    (["tcp/vehicle.local:7447"], ["tcp/vehicle.local:7447"]),
])  # fmt: skip
def test_which_endpoints_open_the_bus_beyond_this_machine(endpoints, open_to):
    assert BusConfig(listen=endpoints).open_beyond_loopback() == open_to
    assert BusConfig(listen=endpoints, auth={"user": "u", "password_file": __file__}
                     ).open_beyond_loopback() == []  # fmt: skip
    assert BusConfig(listen=["tcp/127.0.0.1:1"], multicast_scouting=True
                     ).open_beyond_loopback() == ["multicast scouting"]  # fmt: skip


@pytest.mark.e2e
def test_an_open_bus_beyond_loopback_warns_at_start_up(caplog):
    with caplog.at_level(logging.WARNING, logger="auvgw.bus"):
        with open_session(BusConfig(listen=[f"tcp/127.0.0.1:{free_port()}"])):
            pass
        assert not caplog.records  # loopback only: nothing to say
        with open_session(BusConfig(listen=[f"tcp/0.0.0.0:{free_port()}"])):
            pass
    (rec,) = caplog.records
    assert "no TLS and no authentication" in rec.getMessage()
    assert "tcp/0.0.0.0:" in rec.getMessage() and "docs/security.md" in rec.getMessage()
