"""Read an auvgw ``.rrd`` back (tests, benchmarks, quick checks of a recording).

:func:`read_recording` gives, per entity path, the rows on the ``sensor_time`` timeline in time
order (each component as a list of per-row values) and the static components;
:func:`read_views` lists the views of the layout stored with the recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
from rerun.chunk import RrdReader, StoreEntry

from auvgw.viz.entities import TIMELINE

__all__ = ["EntityRows", "health_metrics", "read_layouts", "read_recording", "read_views"]


@dataclass
class EntityRows:
    """Rows of one entity: ``times`` (ns on ``sensor_time``, sorted; ``written``: as
    written), ``columns`` (component
    name such as ``Scalars:scalars`` -> one value per row) and ``static`` components."""

    times: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    #: the same times in the order the rows were written (chunks in file order)
    written: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    columns: dict[str, list[object]] = field(default_factory=dict)
    static: dict[str, object] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.times)

    def values(self, component: str) -> list[object]:
        """Per-row values of ``component`` (``None`` where a row lacks it)."""
        return self.columns.get(component, [None] * len(self))


def _component_names(rb: pa.RecordBatch) -> list[str]:
    return [n for n in rb.schema.names if ":" in n and not n.startswith("rerun.")]


def read_recording(path: str | Path, timeline: str = TIMELINE) -> dict[str, EntityRows]:
    """Entity path (without the leading ``/``) -> :class:`EntityRows` of the first recording."""
    parts: dict[str, list[tuple[np.ndarray, dict[str, list[object]]]]] = {}
    out: dict[str, EntityRows] = {}
    for chunk in RrdReader(str(path)).stream():
        entity = chunk.entity_path.lstrip("/")
        rb = chunk.to_record_batch()
        rows = out.setdefault(entity, EntityRows())
        if chunk.is_static:
            for name in _component_names(rb):
                rows.static[name] = rb.column(name).to_pylist()[-1]
            continue
        if timeline not in rb.schema.names:
            continue
        times = rb.column(timeline).cast(pa.int64()).to_numpy(zero_copy_only=False)
        cols = {name: rb.column(name).to_pylist() for name in _component_names(rb)}
        parts.setdefault(entity, []).append((times, cols))
    for entity, chunks in parts.items():
        times = np.concatenate([t for t, _ in chunks])
        names = sorted({n for _, c in chunks for n in c})
        merged = {n: [v for t, c in chunks for v in c.get(n, [None] * len(t))] for n in names}
        order = np.argsort(times, kind="stable")
        rows = out[entity]
        rows.times = times[order]
        rows.written = times
        rows.columns = {n: [vals[i] for i in order] for n, vals in merged.items()}
    return out


def health_metrics(rec: dict[str, EntityRows], device: str) -> list[tuple[int, dict[str, float]]]:
    """One device's health statuses as logged (every group ``health/<group>/<device>`` holds a
    row per status): (time ns, metric name such as ``rate_hz`` -> value), in time order."""
    out: list[tuple[int, dict[str, float]]] = []
    for path, rows in sorted(rec.items()):
        parts = path.split("/")
        if len(parts) != 3 or parts[0] != "health" or parts[2] != device:
            continue
        named = rows.static.get("SeriesLines:names")
        names = (
            [str(n).removeprefix(f"{device} ") for n in named] if isinstance(named, list) else []
        )
        for i, (t, vals) in enumerate(zip(rows.times, rows.values("Scalars:scalars"), strict=True)):
            if i == len(out):
                out.append((int(t), {}))
            if isinstance(vals, list):
                out[i][1].update(zip(names, vals, strict=False))
    return out


def read_layouts(path: str | Path) -> list[list[tuple[str, str, str]]]:
    """The views (class, display name, origin) of every layout stored in ``path`` (a logger
    re-sends its layout as views are added; the stores come in no guaranteed order)."""
    reader = RrdReader(str(path))
    return [_views(reader, store) for store in reader.blueprints()]


def read_views(path: str | Path) -> list[tuple[str, str, str]]:
    """(class, display name, origin) of every view in the last layout stored in ``path``."""
    reader = RrdReader(str(path))
    stores = reader.blueprints()
    return _views(reader, stores[-1]) if stores else []


def _views(reader: RrdReader, store: StoreEntry) -> list[tuple[str, str, str]]:
    views: list[tuple[str, str, str]] = []
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" not in rb.schema.names:
            continue
        for cls, name, origin in zip(
            rb.column("ViewBlueprint:class_identifier").to_pylist(),
            rb.column("ViewBlueprint:display_name").to_pylist(),
            rb.column("ViewBlueprint:space_origin").to_pylist(),
            strict=True,
        ):
            views.append((cls[0], name[0] if name else "", origin[0] if origin else ""))
    return views
