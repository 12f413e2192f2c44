"""``auvgw replay FILE.mcap [--speed k] [--vehicle V]``: republish a recording as if live.

Every raw frame goes back on ``auv/<V>/raw/<device>`` with its original attachment (receive
time, sequence, offset), and is decoded through the gateway's own decoder
(:meth:`~auvgw.decoding.DeviceDecoder.decode_raw`, devices and formats from the recorded gateway
configuration) and republished on ``auv/<V>/sensor/<device>/<kind>`` with the same envelope the
live gateway published, so everything downstream runs as if live. ``truth/`` samples are
republished as recorded; the recorded decoded, odometry, SLAM and status samples are not (they
are rebuilt). With no bus option it listens where the gateway would (docs/bus.md).
``--speed k`` replays at k times the recorded pace (1: real time, 0: as fast as possible). The
recorded configuration is served on ``auv/<V>/config/gateway`` (a replay can itself be
recorded) and ``auv/<V>/alive/replay`` is held while it runs. A signed recording
(``FILE.mcap.sig``, ``auvgw sign``) has its signature checked first: one line on stderr, and an
invalid one (or none, with ``--require-signature``) refuses the replay (exit 2).
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import zenoh

from auvgw.bus import (
    RAW_ATTACHMENT,
    Keys,
    add_bus_arguments,
    bus_from_args,
    encode_envelope,
    json_encoding,
    open_cli_session,
    raw_encoding,
    unpack_raw_attachment,
)
from auvgw.commands.common import (
    SubParsers,
    UserError,
    add_command,
    add_decode_config,
    add_signature_arguments,
    check_signature_args,
    decode_config,
    handle_stop_signals,
)
from auvgw.decoding import message_kind
from auvgw.recording import RecordingError, decoders_for, iter_samples, key_section, read_info

log = logging.getLogger(__name__)

_BLOCK = zenoh.CongestionControl.BLOCK
#: recorded sections a replay does not republish: decoded again from raw, or made by stages
DERIVED_SECTIONS = frozenset({"sensor", "nav", "slam", "status"})
_OCTETS = zenoh.Encoding.APPLICATION_OCTET_STREAM


def register(sub: SubParsers) -> None:
    p = add_command(sub, "replay", __doc__)
    p.add_argument("file", type=Path, help="recording made by auvgw record (.mcap)")
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="K",
        help="K x the recorded pace; 0 = as fast as possible (default 1)",
    )
    p.add_argument("--vehicle", default=None, help="publish as this vehicle (default: recorded)")
    add_decode_config(p)
    p.add_argument(
        "--trust-recorded-paths",
        action="store_true",
        help="let the recorded configuration open its site tables and DBC files (by default a "
        "recording is data: devices needing such a file replay raw, undecoded)",
    )
    p.add_argument(
        "--wait-for",
        action="append",
        default=[],
        metavar="NAME",
        help="start once the liveliness token auv/<V>/alive/NAME exists (repeatable)",
    )
    p.add_argument(
        "--wait-timeout",
        type=float,
        default=30.0,
        metavar="S",
        help="give up waiting for --wait-for after S seconds (default 30)",
    )
    add_signature_arguments(p)
    add_bus_arguments(p)
    p.set_defaults(func=run)


def _wait_for_tokens(
    session: zenoh.Session, keys: Keys, names: list[str], stop: threading.Event, timeout: float
) -> None:
    missing = set(names)
    deadline = time.monotonic() + timeout
    while missing and not stop.is_set():
        for reply in session.liveliness().get(keys.alive("*"), timeout=0.5):
            if reply.ok is not None:
                missing.discard(str(reply.ok.key_expr).rsplit("/", 1)[-1])
        if missing and time.monotonic() > deadline:
            raise UserError(
                f"--wait-for: no liveliness token {', '.join(sorted(missing))} under "
                f"{keys.alive('*')} within {timeout:g} s"
            )
        if missing:
            stop.wait(0.1)


def run(args: argparse.Namespace) -> int:
    if args.speed < 0:
        raise UserError(f"--speed must be >= 0 (0 = as fast as possible), got {args.speed}")
    try:
        bus = bus_from_args(args, hub=True)  # replay stands in for the gateway
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    override = decode_config(args)
    if args.file.is_file():  # (a missing file is read_info's one-line error)
        signature = check_signature_args(args.file, args)
        if signature.status == "invalid":
            raise UserError(f"{signature.line}; not replayed")
        print(signature.line, file=sys.stderr, flush=True)
    try:
        info = read_info(args.file)
        decoders = decoders_for(info, override, trust_paths=args.trust_recorded_paths)
    except RecordingError as exc:
        raise UserError(str(exc)) from exc
    cfg = override or info.config
    assert cfg is not None
    vehicle = args.vehicle or info.vehicle or cfg.vehicle
    keys = Keys(vehicle)
    served = cfg.model_copy(update={"vehicle": vehicle}).model_dump_json().encode()
    stop = threading.Event()
    session = open_cli_session(bus)
    sent: Counter[str] = Counter()
    errors = 0
    pubs: dict[str, zenoh.Publisher] = {}

    def publisher(key: str) -> zenoh.Publisher:
        pub = pubs.get(key)
        if pub is None:  # replay may wait; dropping would make it differ from the live run
            pub = pubs[key] = session.declare_publisher(key, congestion_control=_BLOCK)
        return pub

    try:
        token = session.liveliness().declare_token(keys.alive("replay"))
        queryable = session.declare_queryable(
            keys.config("gateway"),
            lambda q: q.reply(
                keys.config("gateway"), served, encoding=json_encoding("GatewayConfig")
            ),
        )
        with handle_stop_signals(stop):
            _wait_for_tokens(session, keys, args.wait_for, stop, args.wait_timeout)
            print(
                f"replaying {args.file} as vehicle {vehicle!r} at speed {args.speed:g}", flush=True
            )
            t0_wall: float | None = None
            t0_log = 0
            for s in iter_samples(args.file):
                if stop.is_set():
                    break
                try:
                    _v, section, rest = key_section(s.key)
                except ValueError:
                    continue
                if t0_wall is None:
                    t0_wall, t0_log = time.monotonic(), s.log_time_ns
                if args.speed > 0:
                    wait = t0_wall + (s.log_time_ns - t0_log) / 1e9 / args.speed - time.monotonic()
                    if wait > 10:
                        log.warning("recorded gap: next sample (%s) in %.0f s", s.key, wait)
                    if wait > 0 and stop.wait(wait):
                        break
                key = keys.all(f"{section}/{rest}")
                if section in DERIVED_SECTIONS:
                    continue  # rebuilt: sensor/ from the raw frames, the rest by live stages
                if section != "raw":
                    publisher(key).put(s.payload, encoding=s.zenoh_encoding or None)
                    sent[key] += 1
                    continue
                if s.attachment is None or len(s.attachment) != RAW_ATTACHMENT.size:
                    log.warning("%s: frame without its attachment; skipped", s.key)
                    continue
                t_ns, seq, offset = unpack_raw_attachment(s.attachment)
                enc = raw_encoding(cfg.devices[rest].format) if rest in cfg.devices else _OCTETS
                publisher(key).put(s.payload, attachment=s.attachment, encoding=enc)
                sent[key] += 1
                dec = decoders.get(rest)
                if dec is None:  # not configured, or its table/DBC not trusted: raw only
                    continue
                item = dec.item(s.payload, offset)
                if item.error is not None:
                    errors += 1
                    log.warning("%s", item.error)
                for msg in item.messages:
                    skey = keys.sensor(rest, message_kind(msg))
                    payload, enc = encode_envelope(
                        msg, rest, t_ns, seq, wire=cfg.devices[rest].format, decoded=True
                    )
                    publisher(skey).put(payload, encoding=enc)
                    sent[skey] += 1
        queryable.undeclare()
        token.undeclare()
    finally:
        session.close()
    per_key = ", ".join(f"{k}: {n}" for k, n in sorted(sent.items()))
    print(
        f"replayed {sum(sent.values())} messages ({errors} decode errors): {per_key or 'nothing'}",
        file=sys.stderr,
    )
    return 0
