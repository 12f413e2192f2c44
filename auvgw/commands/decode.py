"""``auvgw decode --format F FILE``: what is in a capture.

One JSON object per decoded message on stdout (``type`` key first), and a summary on stderr:
messages per type, frames, bad frames, skipped bytes and decode errors. A file with no valid frame
of the named format is a one-line error with exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

from auvgw.commands.common import SubParsers
from auvgw.drivers import registry
from auvgw.drivers.formats import FORMATS, format_from_table, get_format
from auvgw.drivers.framing import DecodeError
from auvgw.drivers.spec import WireError, to_jsonable
from auvgw.ground.errors import UserError


def register(sub: SubParsers) -> None:
    p = sub.add_parser("decode", help="decode a capture file to JSON lines")
    p.add_argument("--format", "-f", required=True, choices=sorted(FORMATS), help="wire format")
    p.add_argument("file", type=Path, help="capture file (raw bytes as received, or a .V4LOG)")
    tables = "/".join(d.format for d in registry.DEVICES if d.table_codec)
    p.add_argument("--table", type=Path, default=None, help=f"site table (TOML) for {tables}")
    p.add_argument("--limit", type=int, default=0, help="stop after N messages (0: all)")
    p.add_argument("--quiet", "-q", action="store_true", help="summary only, no JSON lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    path: Path = args.file
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    if args.table is not None:
        try:
            fmt = format_from_table(args.format, args.table)
        except (OSError, ValueError, KeyError) as exc:
            raise UserError(f"--table {args.table}: {exc}") from exc
    else:
        fmt = get_format(args.format)
    per_type: Counter[str] = Counter()
    decode_errors = 0
    out = sys.stdout
    frames, framer = fmt.frames_of_file(path)
    n = 0
    try:
        for frame in frames:
            try:
                messages = fmt.decode(frame.data)
            except (DecodeError, WireError) as exc:
                decode_errors += 1
                print(f"{path}: frame at byte offset {frame.offset}: {exc}", file=sys.stderr)
                continue
            for msg in messages:
                d = to_jsonable(msg)
                per_type[d["type"]] += 1
                if not args.quiet:
                    out.write(json.dumps(d, separators=(",", ":")) + "\n")
                n += 1
            if args.limit and n >= args.limit:
                break
    except BrokenPipeError:  # `auvgw decode ... | head`
        sys.stderr.close()
        return 0
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: {exc}") from exc
    s = framer.stats
    summary = {
        "file": str(path),
        "format": fmt.name,
        "messages": dict(sorted(per_type.items())),
        "frames": s.frames,
        "bad_frames": s.bad_frames,
        "skipped_bytes": s.skipped_bytes,
        "decode_errors": decode_errors,
    }
    if s.frames == 0 and not args.limit:
        raise UserError(
            f"{path}: no valid {fmt.name} frame found in {s.bytes_in} bytes "
            f"({s.bad_frames} bad frame candidates): is this really {fmt.summary}?"
        )
    print(json.dumps(summary), file=sys.stderr)
    return 0
