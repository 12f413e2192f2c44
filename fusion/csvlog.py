"""Offline import of navigation logs from any vehicle: a CSV/text file and a column map.

A row may carry an attitude sample, a DVL fix, a depth and a position fix at once; each is taken
when its columns are present and not empty/NaN in that row. The column map (TOML, ``auvgw fusion
--csv LOG --columns MAP``) names the log's columns and units::

    delimiter = ","            # default: sniffed from the header (comma, semicolon, tab, space)
    angles = "deg"             # or "rad": roll, pitch, heading, rates
    time_scale = 1.0           # multiply the time column by this to get seconds

    [columns]
    t = "time_s"               # required
    heading = "yaw"            # attitude (roll, pitch default 0 when not mapped)
    roll = "roll"
    pitch = "pitch"
    rate_x = "p"               # optional body rates
    rate_y = "q"
    rate_z = "r"
    dvl_x = "vx"               # DVL velocity components (m/s) in dvl_frame axes
    dvl_y = "vy"
    dvl_z = "vz"
    dvl_fom = "fom"            # optional figure of merit, m/s
    depth = "depth"            # optional pressure depth, m
    fix_north = "gps_n"        # optional position fixes, local NED m
    fix_east = "gps_e"
    fix_sigma = "gps_sigma"    # optional, m (else fix_sigma_m)

    [options]
    dvl_frame = "instrument"   # beam is not supported here (3 columns); instrument/body/earth
    fix_sigma_m = 2.0

Errors name the file, the line and the column (:class:`LogError`); a bad cell in a row loses only
that sample, not the row's others (counted in :attr:`CsvLog.bad_cells`).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from auvgw.fusion.samples import DepthSample, DvlSample, InsSample, PositionFix
from auvgw.ground.errors import DataError, load_settings

__all__ = ["ColumnMap", "CsvLog", "LogError", "load_column_map", "read_csv_log"]


class LogError(DataError):
    """A log or column map that cannot be used (names the file, line and column)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Columns(_Model):
    """Log column names of each quantity (None: not in the log)."""

    t: str
    heading: str | None = None
    roll: str | None = None
    pitch: str | None = None
    rate_x: str | None = None
    rate_y: str | None = None
    rate_z: str | None = None
    dvl_x: str | None = None
    dvl_y: str | None = None
    dvl_z: str | None = None
    dvl_fom: str | None = None
    depth: str | None = None
    fix_north: str | None = None
    fix_east: str | None = None
    fix_sigma: str | None = None


class Options(_Model):
    dvl_frame: Literal["instrument", "body", "earth"] = "instrument"
    fix_sigma_m: float = Field(2.0, gt=0)


class ColumnMap(_Model):
    """The column map file (see the module docstring)."""

    delimiter: str | None = None
    angles: Literal["deg", "rad"] = "deg"
    time_scale: float = Field(1.0, gt=0)
    columns: Columns
    options: Options = Options()


def load_column_map(path: str | Path) -> ColumnMap:
    """Read a column map (TOML); :class:`LogError` names the file and field."""
    return load_settings(path, ColumnMap, LogError)


@dataclass
class CsvLog:
    """Samples read from a log, each list in file order; ``rows`` read, ``bad_cells`` cells
    that were not numbers (their samples dropped; the first is described in ``first_error``)."""

    ins: list[InsSample] = field(default_factory=list)
    dvl: list[DvlSample] = field(default_factory=list)
    depth: list[DepthSample] = field(default_factory=list)
    fixes: list[PositionFix] = field(default_factory=list)
    rows: int = 0
    bad_cells: int = 0
    first_error: str = ""


def read_csv_log(path: str | Path, cmap: ColumnMap) -> CsvLog:
    """Samples of a CSV/text log with a header row, mapped by ``cmap``."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise LogError(f"{path}: cannot read: {exc.strerror}") from exc
    lines = text.splitlines()
    if not lines:
        raise LogError(f"{path}: empty file (a header row naming the columns is needed)")
    delim = cmap.delimiter
    if delim is None:
        try:
            delim = csv.Sniffer().sniff(lines[0], delimiters=",;\t ").delimiter
        except csv.Error:
            delim = ","
    reader = csv.reader(lines, delimiter=delim, skipinitialspace=True)
    header = [h.strip() for h in next(reader)]
    index = {h: i for i, h in enumerate(header)}
    cols = cmap.columns.model_dump()
    for key, name in cols.items():
        if name is not None and name not in index:
            raise LogError(
                f"{path}: line 1: column {name!r} (mapped to {key}) is not in the header "
                f"({', '.join(header)})"
            )
    ang = math.pi / 180.0 if cmap.angles == "deg" else 1.0
    out = CsvLog()

    for lineno, row in enumerate(reader, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        out.rows += 1

        def num(key: str, row: list[str] = row, lineno: int = lineno) -> float | None:
            name = cols[key]
            if name is None:
                return None
            i = index[name]
            cell = row[i].strip() if i < len(row) else ""
            if cell == "":
                return math.nan
            try:
                return float(cell)
            except ValueError:
                out.bad_cells += 1
                if not out.first_error:
                    out.first_error = (
                        f"{path}: line {lineno}: column {name!r}: {cell!r} is not a number"
                    )
                return math.nan

        t = num("t")
        if t is None or not math.isfinite(t):
            if not out.first_error:
                out.first_error = f"{path}: line {lineno}: no time in column {cols['t']!r}"
            out.bad_cells += 1
            continue
        t *= cmap.time_scale
        h = num("heading")
        if h is not None and math.isfinite(h):
            r, p = num("roll"), num("pitch")
            rates = tuple(
                0.0 if (x := num(k)) is None or not math.isfinite(x) else x * ang
                for k in ("rate_x", "rate_y", "rate_z")
            )
            out.ins.append(
                InsSample(
                    t,
                    0.0 if r is None else r * ang,
                    0.0 if p is None else p * ang,
                    h * ang,
                    rates,  # type: ignore[arg-type]
                )
            )
        vel = [num(k) for k in ("dvl_x", "dvl_y", "dvl_z")]
        if vel[0] is not None and any(v is not None and math.isfinite(v) for v in vel):
            v3 = tuple(math.nan if v is None else v for v in vel)
            fom = num("dvl_fom")
            out.dvl.append(
                DvlSample(
                    t,
                    v3,
                    bottom_lock=all(math.isfinite(v) for v in v3),
                    frame=cmap.options.dvl_frame,
                    fom=math.nan if fom is None else fom,
                )
            )
        d = num("depth")
        if d is not None and math.isfinite(d):
            out.depth.append(DepthSample(t, d))
        n, e = num("fix_north"), num("fix_east")
        if n is not None and e is not None and math.isfinite(n) and math.isfinite(e):
            s = num("fix_sigma")
            sigma = s if s is not None and math.isfinite(s) and s > 0 else cmap.options.fix_sigma_m
            out.fixes.append(PositionFix(t, n, e, sigma, "log"))
    return out
