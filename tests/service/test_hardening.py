"""Nothing dies silently: configuration numbers are finite and bounded (an infinite status
period or a 1e300 s back-off is a clear error naming the file and field); a malformed payload on
a bus key is counted and logged, and the stage's worker goes on with the next one (real Zenoh
session)."""

from __future__ import annotations

import logging
import time

import pytest

from auvgw.bus import Keys, open_session
from auvgw.config.bus import BusConfig
from auvgw.config.gateway import ConfigError, parse_gateway_config
from auvgw.stages.fusion import FusionStage, FusionStageConfig
from auvgw.stages.slam import SlamStage, SlamStageConfig

DVL = {"format": "pd0", "transport": {"kind": "serial", "url": "/dev/null-dvl"}}


@pytest.mark.parametrize(
    ("section", "field", "value", "message"),
    [
        (None, "status_period_s", float("inf"), "status_period_s: Input should be a finite"),
        (None, "status_period_s", float("nan"), "status_period_s: Input should be a finite"),
        (None, "status_period_s", 1e9, "status_period_s: Input should be less than or equal"),
        ("dvl", "backoff_initial_s", 1e300, "devices.dvl.backoff_initial_s: Input should be less"),
        ("dvl", "backoff_max_s", float("inf"), "devices.dvl.backoff_max_s: Input should be a fin"),
        ("dvl", "stale_after_s", -1.0, "devices.dvl.stale_after_s: Input should be greater"),
        ("dvl", "partial_frame_max_age_s", float("inf"), "partial_frame_max_age_s: Input should"),
        ("clock", "time_scale", float("inf"), "clock.time_scale: Input should be a finite"),
    ],
)
def test_config_numbers_are_finite_and_bounded(section, field, value, message) -> None:
    data: dict = {"devices": {"dvl": dict(DVL)}}
    if section is None:
        data[field] = value
    elif section == "clock":
        data["clock"] = {field: value, "epoch_ns": 0}
    else:
        data["devices"]["dvl"][field] = value
    with pytest.raises(ConfigError) as err:
        parse_gateway_config(data, source="site.toml")
    assert str(err.value).startswith("site.toml: ") and message in str(err.value)


def test_config_defaults_pass_and_a_bound_value_passes() -> None:
    cfg = parse_gateway_config({"status_period_s": 3600, "devices": {"dvl": dict(DVL)}})
    assert cfg.status_period_s == 3600 and cfg.devices["dvl"].partial_frame_max_age_s == 2.0


MALFORMED = [b"[]", b"\xff\xfe", b"{}", b'{"v": 1}', b"null", b"12", b'"text"']


def _wait(pred, what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


@pytest.mark.e2e
@pytest.mark.parametrize("stage_kind", ["fusion", "slam"])
def test_malformed_bus_payloads_are_counted_logged_and_survived(stage_kind, caplog) -> None:
    keys = Keys("hard1")
    session = open_session(BusConfig())
    caplog.set_level(logging.DEBUG, logger="auvgw.stages")
    try:
        if stage_kind == "fusion":
            stage = FusionStage(FusionStageConfig(vehicle="hard1"), session=session)
            key = keys.sensor("dvl", "ensemble")
        else:
            stage = SlamStage(SlamStageConfig(vehicle="hard1"), session=session)
            key = keys.sensor("msis", "mtheaddata")
        stage.start()
        pub = session.declare_publisher(key)
        for payload in MALFORMED:
            pub.put(payload)
        _wait(lambda: stage.stats.bad_payloads == len(MALFORMED), "bad payload counts")
        assert stage.worker_alive
        # the worker still serves: one more is counted too
        pub.put(b"[]")
        _wait(lambda: stage.stats.bad_payloads == len(MALFORMED) + 1, "one more")
        assert stage.counters()["stage"]["bad_payloads"] == len(MALFORMED) + 1
        pub.undeclare()
        stage.stop()
    finally:
        session.close()
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert any("malformed payload on " + key in r.getMessage() for r in warnings)
    assert not any(r.levelno >= logging.ERROR for r in caplog.records)


@pytest.mark.e2e
def test_raw_sequence_numbers_are_unique_across_a_gateway_restart(tmp_path, shared_data) -> None:
    """Two runs of a gateway over the same capture: the second run's raw sequence numbers
    (``session_id << 32 | n``) repeat none of the first run's."""
    from auvgw.bus import unpack_raw_attachment
    from auvgw.gateway import Gateway
    from auvgw.testing import frame_counters, pd0_frames

    frames = pd0_frames(shared_data, 5)
    capture = tmp_path / "dvl.pd0"
    capture.write_bytes(b"".join(frames))
    cfg = parse_gateway_config(
        {"vehicle": "restart1",
         "devices": {"dvl": {"format": "pd0", "transport": {"kind": "file", "path": str(capture)}}}}
    )  # fmt: skip
    session = open_session(BusConfig())
    runs: list[list[int]] = []
    try:
        for _ in range(2):
            seqs: list[int] = []
            sub = session.declare_subscriber(
                "auv/restart1/raw/dvl",
                lambda s, seqs=seqs: seqs.append(unpack_raw_attachment(s.attachment.to_bytes())[1]),
            )
            started = int(time.time())
            with Gateway(cfg, session=session) as gw:
                _wait(gw.finished.is_set, "end of the capture")
                _wait(lambda seqs=seqs: len(seqs) == len(frames), "every raw frame")
                assert gw.status()["session_id"] == gw.session_id
            sub.undeclare()
            runs.append(seqs)
            _wait(lambda started=started: int(time.time()) > started, "the next second")
    finally:
        session.close()
    assert frame_counters(runs[0]) == frame_counters(runs[1]) == [1, 2, 3, 4, 5]
    assert not set(runs[0]) & set(runs[1])


def test_relative_device_paths_resolve_against_the_config_file(tmp_path, monkeypatch) -> None:
    from auvgw.config.gateway import load_gateway_config

    site = tmp_path / "site"
    site.mkdir()
    (site / "gw.toml").write_text(
        '[devices.dvl]\nformat = "pd0"\ntransport = { kind = "serial", url = "ports/dvl" }\n'
        '[devices.ins]\nformat = "can"\ndbc = "hn100.dbc"\n'
        'transport = { kind = "can", interface = "slcan", channel = "ports/can" }\n'
        '[devices.web]\nformat = "pd0"\ntransport = { kind = "serial", url = "socket://h:1" }\n'
    )
    monkeypatch.chdir(tmp_path)  # anywhere but the config's folder
    cfg = load_gateway_config("site/gw.toml")
    assert cfg.devices["dvl"].transport.url == str(site.resolve() / "ports/dvl")
    assert cfg.devices["ins"].transport.channel == str(site.resolve() / "ports/can")
    assert cfg.devices["web"].transport.url == "socket://h:1"


@pytest.mark.e2e
def test_a_config_with_relative_ports_connects_from_another_directory(procs, tmp_path) -> None:
    """A gateway started elsewhere (systemd starts in /) opens ``url = "ports/dvl"`` next to
    its configuration file and delivers the device's frames."""
    from auvgw.subscribe import GatewaySubscriber
    from auvgw.testing import AUVGW, PtyDevice, endpoint, free_port, wait_until

    site = tmp_path / "site"
    (site / "ports").mkdir(parents=True)
    dvl = PtyDevice(site / "ports" / "dvl")
    ep = endpoint(free_port())
    (site / "gw.toml").write_text(
        f'vehicle = "rel1"\nstatus_period_s = 0.2\n[bus]\nlisten = ["{ep}"]\n'
        '[devices.dvl]\nformat = "pd0"\ntransport = { kind = "serial", url = "ports/dvl" }\n'
    )
    try:
        procs.start(["sh", "-c", f"cd / && exec {AUVGW} run --config {site / 'gw.toml'}"], "gw")
        with GatewaySubscriber("rel1", BusConfig(connect=[ep])) as me:
            st = wait_until(lambda: me.status("dvl"), what="dvl status")
            wait_until(lambda: (me.status("dvl") or {}).get("connected"), what="dvl connected")
            st = me.status("dvl")
    finally:
        dvl.close()
    assert st["connected"] and str(site / "ports" / "dvl") in st["port"]
