"""``auvgw export --ros2 OLD.mcap [--out NEW.mcap]``: convert a recording to MCAP's ROS 2 profile.

Recordings made before the ROS 2 profile (raw channels ``auvgw.raw.v1``, JSON channels) become
what ``auvgw record`` writes now (auvgw/recording.py): raw frames as ``auvgw_msgs/msg/RawFrame``
with their wire format, and, when the old file holds no decoded samples, every raw frame decoded
through the gateway's own decoders (the recorded configuration, or ``--config``) into the
standard ROS 2 types (sensor_msgs/Imu, nav_msgs/Odometry, ...); truth and status as
``auvgw_msgs/msg/Decoded``. The gateway configuration record is carried over, so the new file
replays as the old one did. Prints the topics and counts; exit 2 on an unusable input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from auvgw.config.gateway import GatewayConfig

from auvgw.commands.common import (
    SubParsers,
    UserError,
    add_command,
    add_decode_config,
    decode_config,
)

__all__ = ["export_ros2"]


def register(sub: SubParsers) -> None:
    p = add_command(sub, "export", __doc__)
    p.add_argument("file", type=Path, help="recording to convert (.mcap)")
    p.add_argument("--ros2", action="store_true", required=True, help="ROS 2 profile (CDR)")
    p.add_argument(
        "--out", "-o", type=Path, default=None, metavar="FILE.mcap",
        help="output (default: FILE with .ros2.mcap; never overwritten)",
    )  # fmt: skip
    add_decode_config(p)
    p.set_defaults(func=run)


def export_ros2(src: Path, out: Path, config: GatewayConfig | None = None) -> dict[str, int]:
    """Write ``src`` (any auvgw recording layout) to ``out`` in the ROS 2 profile; returns the
    message counts per topic. Raises :class:`~auvgw.recording.RecordingError`."""
    from auvgw import ros2
    from auvgw.bus import Keys, unpack_raw_attachment
    from auvgw.decoding import message_kind
    from auvgw.recording import (
        GATEWAY_METADATA,
        MESSAGE_ENCODING,
        RAW_ATTACHMENT,
        Ros2McapWriter,
        decoders_for,
        iter_samples,
        key_section,
        read_info,
    )

    info = read_info(src)
    cfg = config or info.config
    vehicle = info.vehicle or (cfg.vehicle if cfg is not None else "auv1")
    has_decoded = any(key_section(k)[1] == "sensor" for k in info.counts if k.startswith("auv/"))
    decoders = decoders_for(info, config) if cfg is not None and not has_decoded else {}
    keys = Keys(vehicle)
    with open(out, "xb") as f:
        w = Ros2McapWriter(f, vehicle)
        if cfg is not None:
            w.wire_formats.update({k: d.format for k, d in cfg.devices.items()})
            w.add_metadata(GATEWAY_METADATA, {
                "vehicle": vehicle, "schema_version": "1",
                "config": info.config_json or cfg.model_dump_json(),
            })  # fmt: skip
        t_first = None
        for s in iter_samples(src):
            t_first = s.log_time_ns if t_first is None else min(t_first, s.log_time_ns)
            if s.message_encoding == MESSAGE_ENCODING:
                continue  # a standard ROS 2 message already: nothing to convert from
            w.write(s.key, s.payload, s.attachment, s.zenoh_encoding, s.log_time_ns)
            _v, section, device = key_section(s.key)
            dec = decoders.get(device) if section == "raw" else None
            if dec is None or s.attachment is None or len(s.attachment) != RAW_ATTACHMENT.size:
                continue
            t_ns, seq, offset = unpack_raw_attachment(s.attachment)
            for msg in dec.item(s.payload, offset).messages:
                kind = message_kind(msg)
                msgs = ros2.to_ros("sensor", device, msg, t_ns, seq, kind)
                w.write_ros(keys.sensor(device, kind), msgs, t_ns, s.log_time_ns, seq)
        w.finish(t_first or 0)
    return dict(w.counts)


def run(args: argparse.Namespace) -> int:
    from auvgw.recording import RecordingError

    out: Path = args.out or args.file.with_suffix(".ros2.mcap")
    if out.exists():
        raise UserError(f"{out}: exists; choose another --out (export never overwrites)")
    if not out.parent.is_dir():
        raise UserError(f"{out}: folder {out.parent} does not exist")
    config = decode_config(args)
    try:
        counts = export_ros2(args.file, out, config)
    except RecordingError as exc:
        out.unlink(missing_ok=True)
        raise UserError(str(exc)) from None
    print(json.dumps({"out": str(out), "counts": counts}), file=sys.stderr)
    print(f"wrote {sum(counts.values())} messages on {len(counts)} topics to {out}")
    return 0
