"""``auvgw record --vehicle V --out FILE.mcap [--duration S]``: record the raw bus traffic.

Subscribes to ``auv/<V>/**``: raw frames with their attachments, decoded sensors, odometry,
SLAM outputs, status and simulation ground truth, and writes them to an MCAP file with the gateway's
configuration (queried from ``auv/<V>/config/gateway``), so ``auvgw replay FILE`` needs nothing
else. Records until SIGINT/SIGTERM or ``--duration`` seconds; prints ``recording ...`` on stdout
once its subscriptions have reached the gateway and ``gateway configuration stored ...`` once
the gateway answered its configuration query (a stop before that tries once more); says so on
stderr when no raw frame arrives
within a few seconds, and exits 1 when it recorded nothing. With ``--sign-key KEY`` (an
Ed25519 key, ``auvgw sign --new-key``; checked before recording) the finished file is signed
into ``FILE.mcap.sig`` (docs/security.md). Layout and rationale: auvgw/recording.py,
docs/gateway.md.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from pathlib import Path

import zenoh

from auvgw.bus import InputWatch, Keys, add_bus_arguments, bus_from_args, open_cli_session
from auvgw.commands.common import (
    SubParsers,
    UserError,
    add_command,
    add_duration,
    handle_stop_signals,
)
from auvgw.recording import McapRecorder

log = logging.getLogger(__name__)


#: at a stop, the recorder keeps listening until no sample came for DRAIN_QUIET_S seconds
#: (at most DRAIN_MAX_S), so what was published before the stop is in the file
DRAIN_QUIET_S = 0.3
DRAIN_MAX_S = 2.0
#: one last query for the gateway configuration when stopped before any answer came (s)
CONFIG_LAST_TRY_S = 3.0


def register(sub: SubParsers) -> None:
    p = add_command(sub, "record", __doc__)
    p.add_argument("--vehicle", default="auv1", help="vehicle name (default auv1)")
    p.add_argument("--out", "-o", required=True, type=Path, metavar="FILE.mcap", help="output file")
    add_duration(p)
    p.add_argument(
        "--wait-gateway",
        type=float,
        default=10.0,
        metavar="S",
        help="wait up to S seconds for the gateway before recording anyway (default 10)",
    )
    p.add_argument(
        "--gateway-zid",
        default=None,
        metavar="ZID",
        help="store only the configuration answered by this Zenoh session id (the gateway's)",
    )
    p.add_argument("--force", action="store_true", help="overwrite FILE.mcap if it exists")
    p.add_argument(
        "--sign-key",
        type=Path,
        default=None,
        metavar="KEY",
        help="sign the finished recording with this Ed25519 key (FILE.mcap.sig; auvgw sign)",
    )
    p.add_argument("--signer", default=None, help="signer name (default: the key file's name)")
    add_bus_arguments(p)
    p.set_defaults(func=run)


def _query_config(
    session: zenoh.Session, keys: Keys, timeout: float, gateway_zid: str | None = None
) -> str | None:
    """The gateway's configuration (JSON text), from the one session that answers, or from
    ``gateway_zid`` when given. Every answer is collected (no consolidation): answers from other
    sessions are dropped with a warning, and several different answers without a pinned Zenoh id
    are all refused (anyone on an open bus can declare a config queryable)."""
    answers: dict[str, str] = {}
    for reply in session.get(
        keys.config("gateway"),
        timeout=timeout,
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
    ):
        if reply.ok is None:
            continue
        zid = str(reply.replier_id.zid) if reply.replier_id is not None else "?"
        if gateway_zid is not None and zid != gateway_zid:
            log.warning(
                "configuration reply from Zenoh id %s ignored (not --gateway-zid %s)",
                zid,
                gateway_zid,
            )
            continue
        text = reply.ok.payload.to_bytes().decode()
        json.loads(text)  # a valid document, or the recorder logs and retries
        answers[zid] = text
    if len(set(answers.values())) > 1:
        log.warning(
            "%d sessions answered %s with different configurations (Zenoh ids %s); none stored: "
            "pass --gateway-zid (the gateway's id is in its status and startup log)",
            len(answers),
            keys.config("gateway"),
            ", ".join(sorted(answers)),
        )
        return None
    return next(iter(answers.values()), None)


def _wait_gateway(
    session: zenoh.Session, keys: Keys, stop: threading.Event, timeout: float
) -> bool:
    """Wait for a gateway status sample: proves the subscriptions declared before reached it."""
    got = threading.Event()
    sub = session.declare_subscriber(keys.status("gateway"), lambda _s: got.set())
    deadline = time.monotonic() + timeout
    try:
        while not stop.is_set() and time.monotonic() < deadline:
            if got.wait(0.05):
                return True
        return False
    finally:
        sub.undeclare()


def run(args: argparse.Namespace) -> int:
    try:
        bus = bus_from_args(args)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    out: Path = args.out
    if not out.parent.is_dir():
        raise UserError(f"{out}: folder {out.parent} does not exist")
    if out.exists() and not args.force:
        raise UserError(f"{out}: exists; choose another --out or pass --force to overwrite it")
    if args.duration is not None and args.duration <= 0:
        raise UserError(f"--duration must be > 0 seconds, got {args.duration}")
    if args.sign_key is not None:  # a key that cannot sign fails now, not after the dive
        from auvgw.signing import load_signing_key

        load_signing_key(args.sign_key)
    keys = Keys(args.vehicle)
    stop = threading.Event()
    session = open_cli_session(bus)
    try:
        try:
            rec = McapRecorder(out, args.vehicle)
        except OSError as exc:
            raise UserError(f"{out}: cannot write: {exc.strerror}") from exc

        last_sample = [time.monotonic()]

        def on_sample(s: zenoh.Sample) -> None:
            last_sample[0] = time.monotonic()
            att = s.attachment
            rec.add(
                str(s.key_expr),
                s.payload.to_bytes(),
                None if att is None else att.to_bytes(),
                str(s.encoding),
            )

        subs = [session.declare_subscriber(keys.all("**"), on_sample)]
        watch = InputWatch(session, [keys.all("raw/**")], "auvgw record", bus)
        with handle_stop_signals(stop):
            try:
                if not _wait_gateway(session, keys, stop, args.wait_gateway) and not stop.is_set():
                    log.warning(
                        "no status from a gateway of vehicle %r within %.0f s; recording anyway",
                        args.vehicle,
                        args.wait_gateway,
                    )
                print(f"recording {keys.all('**')} to {out}", flush=True)

                def fetch_config(timeout_s: float) -> None:
                    try:
                        cfg = _query_config(session, keys, timeout_s, args.gateway_zid)
                    except ValueError as exc:
                        log.warning("gateway configuration is not JSON: %s", exc)
                        return
                    if cfg is not None:
                        rec.set_gateway_config(cfg)
                        print("gateway configuration stored: the recording replays without "
                              "--config", flush=True)  # fmt: skip

                t_end = None if args.duration is None else time.monotonic() + args.duration
                next_query = 0.0
                while (
                    not stop.is_set()
                    and not rec.failed.is_set()
                    and (t_end is None or time.monotonic() < t_end)
                ):
                    if not rec.has_config and time.monotonic() >= next_query:
                        fetch_config(1.0)
                        next_query = time.monotonic() + 1.0
                    wait = 0.1 if t_end is None else max(0.0, min(0.1, t_end - time.monotonic()))
                    stop.wait(wait)
                # samples published before the stop may still be on their way (a decoded
                # message follows its raw frame): keep listening until the bus is quiet
                drain_end = time.monotonic() + DRAIN_MAX_S
                while (
                    not rec.failed.is_set()
                    and time.monotonic() < drain_end
                    and time.monotonic() - last_sample[0] < DRAIN_QUIET_S
                ):
                    time.sleep(0.02)
                if not rec.has_config:  # stopped before an answer came (a prompt Ctrl-C)
                    fetch_config(CONFIG_LAST_TRY_S)
            finally:
                watch.close()
                for s in subs:
                    s.undeclare()
                if not rec.has_config:
                    log.warning(
                        "%s: the gateway configuration was never obtained; replay will need "
                        "--config",
                        out,
                    )
                rec.close()
    finally:
        session.close()
    total = sum(rec.counts.values())
    if rec.error is not None:
        why = rec.error.strerror or str(rec.error)
        raise UserError(
            f"{out}: recording stopped: {why} after {total} messages ({rec.lost} not written); "
            "the file is readable up to the last complete chunk"
        )
    per_key = ", ".join(f"{k}: {n}" for k, n in sorted(rec.counts.items()))
    print(f"recorded {total} messages to {out} ({per_key or 'nothing'})", file=sys.stderr)
    if total == 0:
        print(
            f"auvgw record: nothing recorded: no publisher on {keys.all('**')} "
            f"(bus: {bus.describe()})",
            file=sys.stderr,
        )
        return 1
    if args.sign_key is not None:
        from auvgw.signing import sign_file

        sig = sign_file(out, args.sign_key, args.signer)
        print(f"{out}: signed, {sig}", file=sys.stderr)
    return 0
