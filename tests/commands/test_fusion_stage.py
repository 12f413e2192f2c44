"""The fusion stage: in-process, over a recording (``auvgw fusion --recording``) and on a real
Zenoh bus in separate processes, always against the same filter run offline on the same
messages (identical values, not merely close).

Messages are 10 s of the emulated survey: HN-100 binary frames (device ``ins``), the same
measurements on CAN (``ins_can``, to be ignored: one INS feeds the filter) and PD0 ensembles
(``dvl``), decoded by the drivers (tests/support/fusion_emulated.py).
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import threading
import time
from pathlib import Path

import pytest

from auvgw.bus import Keys, decode_envelope, encode_envelope, open_session, pack_raw_attachment
from auvgw.cli import main as cli_main
from auvgw.config.bus import BusConfig
from auvgw.decoding import message_kind, message_type
from auvgw.drivers.spec import from_jsonable, to_jsonable
from auvgw.fusion import NavFilter, Odometry
from auvgw.fusion.adapters import MessageAdapter
from auvgw.ground.procs import free_endpoint
from auvgw.recording import McapRecorder
from auvgw.stages.fusion import (
    FusionStage,
    FusionStageConfig,
    SettingsError,
    load_stage_config,
    sensor_kinds,
)
from auvgw.subscribe import typed_message
from auvgw.testing import wait_until
from auvgw.testing.fusion_emulated import (
    HOST_EPOCH,
    decode_serial,
    dvl_stream,
    emulate,
    filter_config,
    ins_output,
    survey_scenario,
)

REPO = Path(__file__).resolve().parents[2]
AUVGW = str(REPO / ".venv" / "bin" / "auvgw")
PYTHON = str(REPO / ".venv" / "bin" / "python")
PUBLISHER = str(REPO / "tests" / "fusion_publisher_proc.py")
T0, T1 = 100.0, 110.0
VEHICLE = "fus1"
HOST_EPOCH_NS = int(HOST_EPOCH * 1e9)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """(messages in arrival order, stage settings) of 10 s of the emulated survey."""
    em = emulate(survey_scenario(T1 + 1.0), tmp_path_factory.mktemp("ports"))
    ins = ins_output(em, T0, T1, can=True)
    dvl = dvl_stream(em, T0, T1)
    msgs = decode_serial(ins.serial, "hn100", "ins") + ins.can
    msgs += decode_serial(dvl, "pd0", "dvl")
    msgs.sort(key=lambda m: m[0])
    cfg = FusionStageConfig(
        vehicle=VEHICLE,
        ins_device="ins",
        latency_s={"ins": ins.serial.frame_latency_s, "dvl": dvl.frame_latency_s},
        filter=filter_config(em, T0),
    )
    return [(round(t * 1e9), d, m) for t, d, m in msgs], cfg


def offline(msgs, cfg) -> tuple[list[Odometry], FusionStage]:
    out: list[Odometry] = []
    stage = FusionStage(cfg, on_odometry=out.append)
    for t_ns, device, msg in msgs:
        stage.feed(device, t_ns, msg)
    stage.flush()
    return out, stage


def counts(msgs) -> tuple[int, int, int]:
    n = {d: 0 for d in ("ins", "ins_can", "dvl")}
    for _, d, _ in msgs:
        n[d] += 1
    return n["ins"], n["ins_can"], n["dvl"]


# -- in-process ---------------------------------------------------------------------------------


def test_stage_feed_is_adapter_plus_navfilter_and_counts_everything(data):
    msgs, cfg = data
    out, stage = offline(msgs, cfg)
    n_ins, n_can, n_dvl = counts(msgs)
    assert (n_ins, n_can, n_dvl) == (1001, 1001, 51)
    # the same samples pushed by hand into a NavFilter give the same odometry
    adapter = MessageAdapter("ins", None, cfg.latency_s, warmup_s=cfg.clock_warmup_s)
    nav = NavFilter(cfg.filter)
    ref: list[Odometry] = []
    for t_ns, device, msg in msgs:
        for s in adapter.adapt_all(device, t_ns / 1e9, msg):
            ref += nav.push(s)
    for s in adapter.flush():
        ref += nav.push(s)
    ref += nav.flush()
    assert out == ref and len(out) == n_ins
    c = stage.counters()
    json.dumps(c)  # JSON-ready
    assert c["stage"] == {"received": len(msgs), "bad_payloads": 0, "queue_dropped": 0,
                          "bad_stamps": 0, "published": n_ins,
                          "delivered": 0}  # fed in-process  # fmt: skip
    assert c["adapter"]["ins"] == n_ins and c["adapter"]["dvl"] == n_dvl
    assert c["adapter"]["ignored"] == n_can  # the CAN copy of the same INS is not used twice
    assert c["ins_device"] == "ins" and c["dvl_device"] == "dvl"
    assert c["filter"]["dvl_updates"] == n_dvl and c["last"]["t"] == out[-1].t
    assert out[0].t == pytest.approx(HOST_EPOCH + T0, abs=1e-6)


def test_envelopes_carry_what_the_fusion_uses_exactly(data):
    """Messages rebuilt from the gateway's JSON envelopes adapt to the very same samples (JSON
    keeps every float), so the stage on the bus can give the offline values exactly."""
    msgs, cfg = data
    rebuilt = []
    for t_ns, device, msg in msgs:
        payload, _ = encode_envelope(msg, device, t_ns, 0)
        env = decode_envelope(payload)
        rebuilt.append((env.t_recv_ns, env.device, typed_message(env.type, env.body)))
    a, b = MessageAdapter(), MessageAdapter()
    for (t, d, m), (t2, d2, m2) in zip(msgs, rebuilt, strict=True):
        assert (t2, d2, type(m2)) == (t, d, type(m))
        assert a.adapt(d, t / 1e9, m) == b.adapt(d2, t2 / 1e9, m2)
    assert offline(rebuilt, cfg)[0] == offline(msgs, cfg)[0]


def test_odometry_round_trips_through_json(data):
    msgs, cfg = data
    out, _ = offline(msgs[:300], cfg)
    for o in out[:: max(1, len(out) // 20)]:
        back = from_jsonable(json.loads(json.dumps(to_jsonable(o))))
        assert back == o and isinstance(back, Odometry)


def test_stage_keeps_the_keys_of_its_devices():
    keys = Keys("v")
    default = FusionStage(FusionStageConfig(vehicle="v"))  # sources "ins" and "dvl"
    # the kinds of the attitude and velocity roles, any device: no multibeam ping, no sonar
    assert default.subscription_keys() == [
        f"auv/v/sensor/*/{k}" for k in ("be", "bi", "bs", "ensemble", "ins", "sa")
    ]
    assert default.source_keys() == ["auv/v/sensor/ins/*", "auv/v/sensor/dvl/*"]
    for key in ("auv/v/sensor/ins/ins", "auv/v/sensor/dvl/ensemble", "auv/v/sensor/dvl/bi",
                "auv/v/sensor/dvl/be"):  # fmt: skip
        assert default.wanted(key)
    # never "the first seen": other devices are not wanted, whatever arrives first
    for key in ("auv/v/sensor/x/ins", "auv/v/sensor/d/ensemble"):
        assert not default.wanted(key)
    assert not default.wanted(keys.sensor("mbes", "xyz88")) and not default.wanted("auv/v/sensor")
    # the DVL's compass as the attitude source: its PD6 :SA and PD0 ensembles are wanted
    compass = FusionStage(FusionStageConfig.model_validate({"attitude": "dvl"}))
    assert compass.wanted("auv/v/sensor/dvl/sa") and compass.wanted("auv/v/sensor/dvl/ensemble")
    assert not compass.wanted("auv/v/sensor/ins/ins")
    named = FusionStage(FusionStageConfig(vehicle="v", ins_device="ins", dvl_device="dvl"))
    assert named.wanted(keys.sensor("ins", "ins")) and named.wanted(
        keys.sensor("dvl", "ensemble")
    )
    assert not named.wanted(keys.sensor("ins_can", "ins"))
    assert not named.wanted(keys.sensor("dvl2", "ensemble"))


def test_sensor_kinds_are_the_gateway_key_segments(data):
    msgs, _ = data
    kinds = {message_kind(m) for _, _, m in msgs}
    from auvgw.fusion.adapters import INS_TYPES, PD0_TYPES

    assert kinds <= set(sensor_kinds(INS_TYPES)) | set(sensor_kinds(PD0_TYPES))
    assert kinds == {"ins", "ensemble"}  # one INS kind whatever the wire (serial or CAN)


def test_settings_file_errors_name_the_file_and_field(tmp_path):
    good = tmp_path / "fusion.toml"
    good.write_text(
        'vehicle = "v7"\nins_device = "ins"\n[latency_s]\nins = 0.006\n'
        "[filter]\nheading_error_tau_s = 0.0\n[filter.dvl]\nlever_arm_m = [0.5, 0.0, 0.2]\n"
    )
    cfg = load_stage_config(good)
    assert cfg.vehicle == "v7" and cfg.latency_s == {"ins": 0.006}
    assert cfg.filter.heading_error_tau_s == 0.0 and cfg.filter.dvl.lever_arm_m == (0.5, 0.0, 0.2)
    bad = tmp_path / "bad.toml"
    bad.write_text("[filter]\nheading_error_tau_s = -1\n")
    with pytest.raises(SettingsError, match=r"bad\.toml: filter\.heading_error_tau_s: "):
        load_stage_config(bad)
    bad.write_text("[filter\n")
    with pytest.raises(SettingsError, match=r"bad\.toml: not valid TOML"):
        load_stage_config(bad)
    with pytest.raises(SettingsError, match="cannot read"):
        load_stage_config(tmp_path / "missing.toml")
    # the CLI prints one line and exits 2
    args = ["fusion", "--recording", str(tmp_path / "x.mcap"), "--settings", str(bad)]
    assert cli_main(args) == 2


# -- offline over a recording -------------------------------------------------------------------


def gateway_config_json(vehicle: str) -> str:
    def serial(d: str) -> dict:
        return {"kind": "serial", "url": f"/dev/recorded-{d}"}  # one port each, never opened

    return json.dumps({
        "vehicle": vehicle,
        "devices": {
            "ins": {"format": "hn100", "transport": serial("ins")},
            "dvl": {"format": "pd0", "transport": serial("dvl")},
        },
    })  # fmt: skip


def settings_file(cfg: FusionStageConfig, path: Path) -> Path:
    path.write_text(cfg.model_dump_json())
    return path


def test_recording_mode_runs_the_same_stage_over_an_auvgw_recording(data, tmp_path, capsys):
    """An MCAP recording as ``auvgw record`` writes it (raw frames + attachments + gateway
    configuration): ``auvgw fusion --recording`` gives the odometry of the stage fed live."""
    msgs, cfg = data
    from auvgw.drivers import hn100, pd0

    serial = [(t, d, m) for t, d, m in msgs if d != "ins_can"]  # the recording's devices
    rec_path = tmp_path / "run.mcap"
    rec = McapRecorder(rec_path, VEHICLE)
    rec.set_gateway_config(gateway_config_json(VEHICLE))
    keys = Keys(VEHICLE)
    offsets = {"ins": 0, "dvl": 0}
    for seq, (t_ns, device, msg) in enumerate(serial):
        raw = hn100.CODEC.encode(msg) if device == "ins" else pd0.encode(msg)
        att = pack_raw_attachment(t_ns, seq, offsets[device])
        offsets[device] += len(raw)
        rec.add(keys.raw(device), raw, att, "application/octet-stream")
    rec.close()
    out_file = tmp_path / "odo.jsonl"
    settings = settings_file(cfg, tmp_path / "fusion.json")
    rc = cli_main(["fusion", "--recording", str(rec_path), "--settings", str(settings),
                   "--out", str(out_file)])  # fmt: skip
    assert rc == 0
    got = [from_jsonable(json.loads(x)) for x in out_file.read_text().splitlines()]
    assert got == offline(serial, cfg)[0] and len(got) == 1001
    text = capsys.readouterr().out
    assert "1001 odometry samples over 10.0 s" in text and "distance travelled" in text


# -- on the bus, separate processes ---------------------------------------------------------------


class Proc:
    """A child process; stdout lines are queued by a thread, stderr goes to a file."""

    def __init__(self, args: list[str], log: Path) -> None:
        self.log = log
        self._err = open(log, "wb")  # noqa: SIM115 - closed in stop()
        self.p = subprocess.Popen(
            args, stdout=subprocess.PIPE, stderr=self._err, text=True, cwd=REPO,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        assert self.p.stdout is not None
        for line in self.p.stdout:
            self.lines.put(line.rstrip("\n"))

    def wait_line(self, prefix: str, timeout: float = 60.0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                if self.p.poll() is not None:
                    break
                continue
            self.seen.append(line)
            if line.startswith(prefix):
                return line
        self._err.flush()
        raise AssertionError(
            f"no line {prefix!r} (got {self.seen[-5:]}); stderr:\n{self.log.read_text()[-3000:]}"
        )

    def wait(self, timeout: float = 30.0) -> int:
        return self.p.wait(timeout)

    def stop(self) -> int | None:
        if self.p.poll() is None:
            self.p.terminate()
            try:
                self.p.wait(20)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(5)
        self._err.close()
        return self.p.returncode


#: hostile envelopes on the DVL's key (issue 27): an old-format JSON envelope whose stamp is
#: 1e300 (it stopped the fusion's odometry for good), one a century ahead within int64, a
#: boolean stamp, a negative sequence, and a JSON body nested 20,000 deep
FORGED: list[bytes] = [
    json.dumps({"v": 1, "type": "pd0.Ensemble", "device": "dvl", "t_recv_ns": 1e300, "seq": 1,
                "msg": {}}).encode(),
    json.dumps({"v": 1, "type": "pd0.Ensemble", "device": "dvl",
                "t_recv_ns": HOST_EPOCH_NS + 100 * 365 * 86_400 * 10**9, "seq": 2,
                "msg": {}}).encode(),
    b'{"v": 1, "type": "pd0.Ensemble", "device": "dvl", "t_recv_ns": true, "seq": 3, "msg": {}}',
    b'{"v": 1, "type": "pd0.Ensemble", "device": "dvl", "t_recv_ns": 5, "seq": -1, "msg": {}}',
    b'{"v": 1, "msg": ' + b"[" * 20_000 + b"]" * 20_000 + b"}",
]


@pytest.mark.e2e
def test_stage_process_publishes_the_offline_odometry(data, tmp_path):
    """Three processes: this test (a Zenoh router and the odometry subscriber), ``auvgw
    fusion`` (the stage) and a publisher of gateway envelopes. The odometry on
    ``auv/<v>/nav/odometry`` equals the offline run on the same messages, sample for sample."""
    _run_stage_process(data, tmp_path, forged=[])


@pytest.mark.e2e
def test_forged_envelopes_mid_stream_change_no_odometry(data, tmp_path):
    """The same run with the :data:`FORGED` envelopes sent on the DVL's key in the middle of the
    stream: every one is refused and counted, and the odometry is the same, sample for sample,
    at the same rate (issue 27)."""
    st = _run_stage_process(data, tmp_path, forged=FORGED)
    # the far-future stamp is a valid envelope but not a plausible time: refused by the clock;
    # it carries an empty body, refused first as an unusable message, so it counts there
    assert st["stage"]["bad_payloads"] + st["stage"]["bad_stamps"] == len(FORGED)


def _run_stage_process(data, tmp_path, forged: list[bytes]) -> dict:
    """The three-process run; ``forged`` payloads are published on the DVL's key halfway
    through. Returns the stage's last status."""
    msgs, cfg = data
    keys = Keys(VEHICLE)
    n_ins, _n_can, n_dvl = counts(msgs)
    env_file = tmp_path / "envelopes.jsonl"
    half = len(msgs) // 2
    with env_file.open("w") as f:
        for seq, (t_ns, device, msg) in enumerate(msgs):
            if seq == half:
                for bad in forged:
                    item = {"key": keys.sensor("dvl", "ensemble"), "type": "pd0.Ensemble",
                            "payload": bad.hex(), "forged": True}  # fmt: skip
                    f.write(json.dumps(item) + "\n")
            payload, _ = encode_envelope(msg, device, t_ns, seq)
            key = keys.sensor(device, message_kind(msg))
            item = {"key": key, "type": message_type(msg), "payload": payload.hex()}
            f.write(json.dumps(item) + "\n")
    # what the stage process will see: the envelopes' messages rebuilt from JSON, in order
    rebuilt = []
    for line in env_file.read_text().splitlines():
        item = json.loads(line)
        if item.get("forged"):
            continue
        env = decode_envelope(bytes.fromhex(item["payload"]))
        rebuilt.append((env.t_recv_ns, env.device, typed_message(env.type, env.body)))
    expected, _ = offline(rebuilt, cfg)
    assert len(expected) == n_ins

    ep = free_endpoint()
    settings = tmp_path / "fusion.json"
    settings.write_text(cfg.model_copy(update={"status_period_s": 0.2}).model_dump_json())
    received: list[bytes] = []
    session = open_session(BusConfig(mode="router", listen=[ep]))
    procs: list[Proc] = []
    try:
        sub = session.declare_subscriber(
            keys.odometry(), lambda s: received.append(s.payload.to_bytes())
        )
        args = ["-v", "fusion", "--vehicle", VEHICLE, "--mode", "client", "--connect", ep]
        stage = Proc([AUVGW, *args, "--settings", str(settings)], tmp_path / "stage.err")
        procs.append(stage)
        stage.wait_line("fusion running")
        pub = Proc([PYTHON, PUBLISHER, "--connect", ep, "--vehicle", VEHICLE,
                    "--file", str(env_file)], tmp_path / "publisher.err")  # fmt: skip
        procs.append(pub)
        every = sorted({keys.sensor(d, message_kind(m)) for _, d, m in msgs})
        n_lines = len(msgs) + len(forged)
        assert pub.wait_line("published") == f"published {n_lines} matched {','.join(every)}"
        assert pub.wait() == 0

        def status() -> dict | None:
            for reply in session.get(keys.status("fusion"), timeout=2.0):
                if reply.ok is not None:
                    return json.loads(reply.ok.payload.to_bytes())
            return None

        # every envelope of the configured INS and the discovered DVL reached the stage (the
        # CAN copy of the INS is dropped by key, before it is parsed)
        n_used = n_ins + n_dvl
        wait_until(lambda: (s := status()) is not None and s["stage"]["received"] == n_used,
                   90.0, what="the stage to receive every envelope")  # fmt: skip
        wait_until(lambda: (s := status()) is not None
                   and s["stage"]["bad_payloads"] + s["stage"]["bad_stamps"] == len(forged),
                   30.0, what="every forged envelope counted")  # fmt: skip
        st = status()
        assert st["adapter"]["ins"] == n_ins and st["adapter"]["dvl"] == n_dvl
        assert st["adapter"]["ignored"] == 0
        assert st["ins_device"] == "ins" and st["dvl_device"] == "dvl"
        assert all(v == 0 for v in st["buffer"].values()), st["buffer"]  # none arrived too late
        # all but the fixed-lag tail (0.2 s of INS samples) is published already
        wait_until(lambda: len(received) >= n_ins - 25, 90.0, what="odometry")
        # SIGTERM: the stage flushes the filter and publishes the held-back tail
        assert stage.stop() == 0
        wait_until(lambda: len(received) == n_ins, 10.0, what="the flushed odometry")
        sub.undeclare()
    finally:
        for p in procs:
            p.stop()
        session.close()
    got = []
    for payload in received:
        env = decode_envelope(payload)
        assert env.type == "Odometry" and env.device == "fusion"
        got.append(from_jsonable(env.body, Odometry))
    assert [e.seq for e in map(decode_envelope, received)] == list(range(1, n_ins + 1))
    assert got == expected  # identical values, sample for sample
    assert got[-1].t == pytest.approx(HOST_EPOCH + T1, abs=1e-6)
    return st
