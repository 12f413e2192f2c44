"""The health views: per-device series split by unit (rate, age, lag, flags...), the
cumulative counters as one table, named series of other units (the pilot's) and text events."""

from __future__ import annotations

import math
from collections.abc import Iterable

import rerun as rr

from auvgw.viz import entities as ent
from auvgw.viz.scene import Scene
from auvgw.viz.views.base import View

__all__ = ["Event", "Health", "Series"]

#: the health views' colours, one per device in order of appearance
_HEALTH_PALETTE: tuple[tuple[int, int, int], ...] = (
    (80, 160, 255), (255, 160, 40), (90, 220, 110), (230, 80, 220), (255, 90, 90),
    (120, 230, 230), (220, 220, 80), (170, 130, 255), (200, 200, 200), (255, 200, 150),
)  # fmt: skip

Metrics = tuple[tuple[str, float], ...]


class Series(View):
    """Named series of one unit on an entity (e.g. ``pilot/fins``): the names of its first row
    name (and colour) the series, later rows are matched by name (missing: NaN)."""

    kind = "series"

    def __init__(self, scene: Scene) -> None:
        super().__init__(scene)
        self._names: dict[str, tuple[str, ...]] = {}

    def log(self, path: str, t: float, values: Metrics) -> None:
        self._series(path, t, values)

    def _series(
        self,
        path: str,
        t: float,
        metrics: Iterable[tuple[str, float]],
        device: str | None = None,
        colour: tuple[int, int, int] | None = None,
    ) -> None:
        """Scalars of named series on ``path``, named (``<device> <name>``) and coloured
        (``colour``, else one per series) at the path's first row."""
        metrics = tuple(metrics)
        names = self._names.get(path)
        if names is None:
            names = self._names[path] = tuple(k for k, _ in metrics)
            prefix = f"{device} " if device is not None else ""
            colours = (
                [colour] * len(names)
                if colour is not None
                else [_HEALTH_PALETTE[i % len(_HEALTH_PALETTE)] for i in range(len(names))]
            )
            series = rr.SeriesLines(names=[f"{prefix}{k}" for k in names], colors=colours,
                                    widths=[1.5] * len(names))  # fmt: skip
            self.scene.static(path, lambda: series)
        got = dict(metrics)
        self.scene.append(path, "scalars", t, tuple(got.get(n, math.nan) for n in names))


class Health(Series):
    """One status of a device: each metric on its group's series
    (``health/<device>/<group>``, one unit per view: :func:`~auvgw.viz.entities.health_group`)
    in the device's colour; cumulative counters also in the table ``health/counters`` (every
    ``counters_period_s`` of device time and at the end)."""

    kind = "health"

    def __init__(self, scene: Scene) -> None:
        super().__init__(scene)
        self._device_colours: dict[str, tuple[int, int, int]] = {}
        self._counters: dict[str, dict[str, float]] = {}
        self._counters_dirty = False
        self._counters_t = -math.inf

    def log(self, device: str, t: float, values: Metrics) -> None:
        groups: dict[str, list[tuple[str, float]]] = {}
        for name, v in values:
            group = ent.health_group(name)
            if group is None:  # the table, and a series no view shows (for tools, tests)
                self._counters.setdefault(device, {})[name] = v
                self._counters_dirty = True
                group = "count"
            groups.setdefault(group, []).append((name, v))
        for group, metrics in groups.items():
            self._series(ent.health_path(device, group), t, metrics, device, self._colour(device))
        if self._counters_dirty and t - self._counters_t >= self.options.counters_period_s:
            self._log_counters(t)

    def flush(self, final: bool, t_last: float) -> None:
        if final and self._counters_dirty and t_last:
            self._log_counters(max(t_last, self._counters_t))

    def _colour(self, device: str) -> tuple[int, int, int]:
        """One colour per device (or stage) across the health views, in order of appearance."""
        if device not in self._device_colours:
            palette = _HEALTH_PALETTE
            self._device_colours[device] = palette[len(self._device_colours) % len(palette)]
        return self._device_colours[device]

    def _log_counters(self, t: float) -> None:
        """Every component's latest cumulative counters as one markdown table at ``t``."""
        self._counters_t, self._counters_dirty = t, False
        lines = ["| component | counters |", "|---|---|"]
        for device, counts in sorted(self._counters.items()):
            cells = ", ".join(
                f"{k} {v:.0f}" if float(v).is_integer() else f"{k} {v:.3g}"
                for k, v in counts.items()
                if math.isfinite(v)
            )
            lines.append(f"| {device} | {cells} |")
        self.scene.set_time(t)
        self.scene.rec.log(
            ent.HEALTH_COUNTERS, rr.TextDocument("\n".join(lines), media_type="text/markdown")
        )


class Event(View):
    """A text event of one device on ``health/<device>/events`` at ``level``."""

    kind = "event"

    def log(self, device: str, t: float, text: str, level: str) -> None:
        self.scene.set_time(t)
        self.scene.rec.log(ent.events_path(device), rr.TextLog(text, level=level))
