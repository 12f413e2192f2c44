"""``auvgw verify``: check recordings for damage.

    auvgw verify run.mcap [more.mcap ...] [--key vehicle.sign.pub] [--require-signature]

Reads every chunk of each recording and checks its CRC (and that it decompresses to its stated
size), reads the summary, and prints one line per problem (file, byte offset, what is wrong, the
time range of the messages it cost) and one summary line per file. A recording signed with
``auvgw sign`` (``F.mcap.sig`` beside it) has its signature checked too: one line, ``signed by
X, valid`` or ``INVALID: file changed after signing`` (or another reason). Exit 0: every file
clean (and its signature valid where there is one); 1: damage found or a signature invalid
(missing, with ``--require-signature``; what could be read is still readable: ``auvgw replay``
and the ``--recording`` readers skip a damaged chunk with one line); 2: a file that is not a
recording, or a key that cannot be read.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from auvgw.commands.common import (
    SubParsers,
    add_command,
    add_signature_arguments,
    check_signature_args,
)


def register(sub: SubParsers) -> None:
    p = add_command(sub, "verify", __doc__)
    p.add_argument("files", type=Path, nargs="+", metavar="FILE.mcap")
    add_signature_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from auvgw.recording import RecordingError, ScanReport, scan_recording

    bad = 0
    for path in args.files:
        report = ScanReport()
        try:
            for _ in scan_recording(path, report):
                pass
        except RecordingError as exc:
            from auvgw.ground.errors import UserError

            raise UserError(str(exc)) from None
        for d in report.damaged:
            print(d.line(path))
        how = "through its index" if report.indexed else "by a linear scan (no readable summary)"
        state = "clean" if not report.damaged else f"{len(report.damaged)} damaged"
        signature = check_signature_args(path, args)
        print(signature.line)  # (the file's summary line stays its last)
        print(f"{path}: {report.chunks} chunks, {report.messages} messages read {how}: {state}")
        bad += bool(report.damaged) or signature.status == "invalid"
    return 1 if bad else 0
