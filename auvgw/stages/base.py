"""The stage base class: what every bus stage (fusion, SLAM, magnetic, bathymetric, Rerun) shares.

A :class:`Stage` owns the plumbing; a subclass gives only what is its own:

* **inputs**: :meth:`Stage.input_keys` (key expressions to subscribe to) and, optionally,
  :meth:`Stage.wanted` (a cheap filter on a key, run in the Zenoh callback before anything is
  parsed);
* **per-message handling**: :meth:`Stage.feed` ``(device, t_recv_ns, message)`` (the gateway's
  ``on_message`` signature; :meth:`Stage.from_source` keeps one device per role: the configured
  one, else the first seen) and, for stages that use the fusion's odometry,
  :meth:`Stage.feed_odometry`; :meth:`Stage.dispatch` routes each decoded bus message to them
  (override it for anything else);
* **outputs**: the names in :attr:`Stage.outputs`, each published on :meth:`Stage.key`
  ``(what)`` with :meth:`Stage.publish`, :meth:`Stage.publish_message` (a declared message as an
  envelope) or :meth:`Stage.publish_json` (which all call
  ``on_publish(key, payload, t_ns)``, the in-process hook);
* **status**: :attr:`Stage.status_schema` (None: no status, queryable nor liveliness on the bus)
  and :meth:`Stage.status_fields`, merged into :meth:`Stage.counters` after the common fields;
* **flush**: :meth:`Stage.flush`, called at :meth:`Stage.stop` after the queue is drained;
* **its own start and stop**: :meth:`Stage.on_start` (its servers, tokens, extra
  subscriptions: after the outputs, status and worker are up, before the subscriptions and the
  liveliness token) and :meth:`Stage.on_stop` (stop what feeds the worker besides the
  subscriptions: timers, command subscriptions; first thing at stop), with what must live
  until the end handed to :meth:`Stage.keep` (withdrawn after the last status, the last kept
  first);
* **its own reading and reporting**: :meth:`Stage.read_payload` (a payload that is not read as an
  envelope: the Rerun stage's JSON sections, the ROS 2 stages' conversions), :meth:`Stage.accepts`
  (which in-process messages :meth:`Stage.post` queues), :attr:`Stage.batch_s` (one worker
  call per batch, for the posted messages and the bus samples alike; :meth:`Stage.feed_batch`
  takes the messages, one by one unless the stage writes them in one pass) and
  :meth:`Stage.on_status` (health reported elsewhere than the bus, at each status period and at
  stop).

The methods a subclass gives are marked :func:`hook`; it never overrides any other public method
of the base (``tests/service/test_stage_hooks.py`` walks them all).

The base does the rest. Zenoh callbacks only copy the payload into a bounded queue (or, with
:attr:`Stage.batch_s`, the batch; counting ``queue_dropped`` when it is full: a callback never
blocks the network thread); one worker thread decodes the envelopes
(:func:`auvgw.bus.decode_envelope`, then the typed message) and feeds them in arrival order, so
the subclass's state is touched by one thread at a time (take
``self._lock`` in ``feed`` when it is also fed in-process). A malformed payload, an unknown type
or a message whose handling fails is counted (``bad_payloads``) and logged (the first and every
100th), never stops the worker. The worker publishes :meth:`Stage.counters` on
``auv/<v>/status/<component>`` every ``status_period_s`` (host clock: health, not data) and a
queryable on the same key answers them on demand; the liveliness token
``auv/<v>/alive/<component>`` is declared last, so once it is seen the subscriptions are in
place. :meth:`Stage.stop` withdraws the subscriptions, lets the worker drain the queue for as long
as it makes progress (the :class:`~auvgw.ground.worker.Worker` base), flushes, publishes a last
status and withdraws everything else.

In-process, a stage is fed on the calling thread (:meth:`Stage.feed`) or queued for its worker
(:meth:`Stage.post`, :meth:`Stage.post_odometry`: the feeding thread is never held up).
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, TypeVar

import zenoh
from pydantic import BaseModel, ConfigDict, Field

from auvgw.bus import (
    SCHEMA_VERSION,
    Envelope,
    Keys,
    Undeclarable,
    decode_envelope,
    encode_envelope,
    json_encoding,
    undeclare,
)
from auvgw.fusion.odometry import Odometry
from auvgw.ground.worker import Worker
from auvgw.stages import StampGuard, log_bad_payload

__all__ = ["DROP", "BusCounters", "OnPublish", "PipelineStage", "Stage", "StageConfig", "hook"]

log = logging.getLogger(__name__)

#: outputs and status never stall the stage on a slow subscriber
DROP = zenoh.CongestionControl.DROP

#: a stage's in-process publication hook: (key, payload, stamp ns)
OnPublish = Callable[[str, bytes, int], object]
#: a queued call: the bound method and its arguments
_Item = tuple[Callable[..., object], tuple[object, ...]]

_F = TypeVar("_F", bound=Callable[..., object])


def hook(fn: _F) -> _F:
    """Mark a method of :class:`Stage` as one a subclass gives (overrides); every other public
    method of the base is its own (``tests/service/test_stage_hooks.py``)."""
    fn.__stage_hook__ = True  # type: ignore[attr-defined]
    return fn


@dataclass
class BusCounters:
    """The counters every stage keeps (a stage's stats dataclass extends it)."""

    received: int = 0  #: messages used or envelopes received (each stage says which)
    bad_payloads: int = 0  #: envelopes that could not be parsed, rebuilt or handled
    queue_dropped: int = 0  #: payloads dropped because the worker fell behind
    bad_stamps: int = 0  #: envelopes whose stamp was implausible against the stage's clock


class StageConfig(BaseModel):
    """The settings every stage's config has: ``vehicle`` (the key root ``auv/<vehicle>``),
    ``status_period_s`` (s between status publications, host clock) and ``queue_size``
    (payloads waiting for the worker before ``queue_dropped`` counts)."""

    model_config = ConfigDict(extra="forbid")

    vehicle: str = "auv1"
    status_period_s: float = Field(1.0, gt=0)
    queue_size: int = Field(100_000, ge=1)
    #: a bus stamp further than this from the stage's clock is refused (``bad_stamps``) unless
    #: 20 in a row agree on the new time (:class:`~auvgw.stages.StampGuard`), s of stamp time
    max_stamp_jump_s: float = Field(300.0, gt=0, le=86_400.0)


class Stage(Worker[_Item]):
    """Queue, worker, envelope decoding, status, liveliness and stop/flush of a bus stage (see
    the module docstring for the subclass contract).

    ``config``: vehicle, status period, queue size and stamp window; ``stats``: the stage's
    counters (a :class:`BusCounters`, published under ``"stage"``); ``session``: the Zenoh
    session (None: in-process only); ``on_publish(key, payload, t_ns)``: called at every
    publication; ``keys``: the vehicle's key expressions (None: ``Keys(config.vehicle)``).

    The queue and the worker thread are the :class:`~auvgw.ground.worker.Worker` base's (items:
    a bound call ``(fn, args)``; its tick publishes the status).
    """

    #: short name: logs, the worker thread, the default component
    name: ClassVar[str] = "stage"
    #: type name of the status JSON (``json_encoding``); None: no status, queryable, liveliness
    status_schema: ClassVar[str | None] = None
    #: output names, each declared as a publisher on :meth:`key` at :meth:`start`
    outputs: ClassVar[tuple[str, ...]] = ()
    #: outputs of bulk data (maps, point clouds) put at ``Priority.DATA_LOW``: Zenoh keeps a
    #: transmission queue per priority, so a burst of them cannot fill the queue the small
    #: outputs (poses) wait in and have those dropped (DROP gives up on a full queue after 1 ms)
    bulk_outputs: ClassVar[frozenset[str]] = frozenset()

    def __init__(
        self,
        config: StageConfig,
        stats: BusCounters,
        session: zenoh.Session | None = None,
        *,
        on_publish: OnPublish | None = None,
        keys: Keys | None = None,
    ) -> None:
        super().__init__(config.queue_size, period_s=config.status_period_s,
                         thread_name=f"{self.name}-stage")  # fmt: skip
        self.keys = keys or Keys(config.vehicle)
        self.stats = stats
        self.session = session
        self.on_publish = on_publish
        self.status_period_s = config.status_period_s
        self._lock = threading.RLock()  # the subclass's state and the counters
        self._drop_lock = threading.Lock()  # queue_dropped (Zenoh callbacks, never _lock)
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._status_pub: zenoh.Publisher | None = None
        self._decls: list[Undeclarable] = []
        self._started = self._stopped = False
        self._stamps = StampGuard(config.max_stamp_jump_s)
        self._seq = 0  # envelopes published (publish_message)
        #: the device used in each role (:meth:`from_source`); None: the first one seen
        self.sources: dict[str, str | None] = {}
        #: s a batch of posted messages and bus samples waits for more (:meth:`post`); 0: one
        #: worker call per message and per sample
        self.batch_s = 0.0
        self._batch: deque[tuple[str, int, object]] = deque()  # posted, waiting for the worker
        self._samples: deque[tuple[str, bytes, int]] = deque()  # bus samples, likewise
        self._batch_max = config.queue_size  # each deque's bound, as the worker's queue's
        self._batch_queued = False

    # -- what a subclass gives ------------------------------------------------------------------
    @property
    @hook
    def component(self) -> str:
        """Status / liveliness component name (default :attr:`name`)."""
        return self.name

    @hook
    def key(self, what: str) -> str:
        """The key expression of output ``what``."""
        raise NotImplementedError(f"{type(self).__name__} has no output {what!r}")

    @hook
    def input_keys(self) -> list[str]:
        """The key expressions the stage subscribes to."""
        return []

    @hook
    def wanted(self, key: str) -> bool:
        """Whether a sample on ``key`` is queued (runs in the Zenoh callback: keep it cheap)."""
        return True

    @hook
    def feed(self, device: str, t_recv_ns: int, message: object) -> object:
        """One decoded message of ``device`` received at ``t_recv_ns`` (the stamp clock, ns)."""
        return None

    @hook
    def feed_odometry(self, o: Odometry) -> None:
        """One fusion odometry sample (stages that use it override this)."""

    def from_source(self, role: str, device: str) -> bool:
        """Whether a message of ``device`` in ``role`` (a device-registry role: ``sonar``,
        ``swath``, ``field``...) is used: the stage takes one device per role, the one named in
        :attr:`sources` (from its settings), else the first one seen (then fixed), so a serial and
        a CAN copy of one sensor, or two sensors of a kind, never both feed a pipeline."""
        with self._lock:
            want = self.sources.get(role)
            if want is None:
                self.sources[role] = want = device
            return device == want

    @hook
    def dispatch(self, env: Envelope, message: object) -> None:
        """One decoded bus message: odometry to :meth:`feed_odometry`, the rest to
        :meth:`feed` with the envelope's device and receive stamp."""
        if isinstance(message, Odometry):
            self.feed_odometry(message)
        else:
            self.feed(env.device, int(env.t_recv_ns), message)

    @hook
    def status_fields(self) -> dict[str, object]:
        """The stage's own status fields (JSON-ready), after the common ones."""
        return {}

    @hook
    def flush(self) -> object:
        """End of data: publish what is held back (called by :meth:`stop`)."""
        return None

    @hook
    def on_start(self, subscribe: bool) -> None:
        """The stage's own start, called once by :meth:`start` after the outputs, the status
        and the worker are up and before the subscriptions (``subscribe``: whether they are
        made) and the liveliness token: declare servers, tokens and extra subscriptions here,
        each handed to :meth:`keep`."""

    @hook
    def on_stop(self) -> None:
        """The stage's own stop, called once first thing by :meth:`stop` (before the
        subscriptions are withdrawn and the queue drained): stop what feeds the worker besides
        the subscriptions (timers, command subscriptions)."""

    def keep(self, decl: Undeclarable) -> Undeclarable:
        """Hold ``decl`` (a Zenoh declaration, or anything with ``undeclare()``) until
        :meth:`stop`, which withdraws it after the last status (a subscription: with the
        stage's subscriptions, before the queue is drained), the last kept first; ``decl``."""
        self._decls.append(decl)
        return decl

    @hook
    def accepts(self, device: str, message: object) -> bool:
        """Whether :meth:`post` queues an in-process message of ``device`` (runs on the posting
        thread: keep it cheap); the base takes every one."""
        return True

    @hook
    def read_payload(self, key: str, payload: bytes, t_arrival_ns: int | None) -> object:
        """How the stage reads one bus payload (:meth:`handle_sample`; ``t_arrival_ns``: host
        arrival time, ns, None: unknown). The base: the envelope decoded, its stamp checked and
        the typed message given to :meth:`dispatch`, a malformed payload, an unknown type or a
        failed handling counted (``bad_payloads``) and logged. A stage whose payloads are not
        (only) envelopes reads them here (the Rerun stage: JSON sections)."""
        from auvgw.subscribe import envelope_message

        try:
            env = decode_envelope(payload, key)
            msg = envelope_message(env)
            if msg is None:
                raise ValueError(f"unknown or unusable message type {env.type!r}")
        except Exception as exc:  # any malformed payload ([] on a sensor key...): count, go on
            self._bad_payload(key, exc)
            return None
        if not self._stamps.accept(env.t_recv_ns):  # one forged stamp never moves the clock
            with self._lock:
                n = self.stats.bad_stamps
                self.stats.bad_stamps += 1
            clock = self._stamps.clock_ns
            log_bad_payload(self.name, key, ValueError(
                f"stamp {env.t_recv_ns} ns is {(env.t_recv_ns - (clock or 0)) / 1e9:+.3g} s from "
                f"the stage's clock; refused"), n)  # fmt: skip
            return None
        self.dispatch(env, msg)
        return None

    @hook
    def on_status(self) -> None:
        """The stage's own report at each status period and at :meth:`stop`, after the status
        is put on the bus (health shown elsewhere, a periodic re-publication)."""

    # -- in-process use -------------------------------------------------------------------------
    def post(self, device: str, t_recv_ns: int, message: object) -> None:
        """:meth:`feed` on the worker thread (after :meth:`start`): returns at once. Only what
        :meth:`accepts` is queued; with :attr:`batch_s` > 0 the first message of a batch queues
        one call that waits ``batch_s`` and then takes every bus sample (:meth:`handle_sample`)
        and every message (:meth:`feed_batch`) that came meanwhile: a worker's run costs more
        than most messages (its code and data gone cold since the last, docs/ros2.md#cost), so
        at 1,000 messages/s and 100 ms it runs 10 times a second, not 1,000. A batch holds at
        most ``queue_size`` messages (and as many samples): more, while the worker is that far
        behind, are dropped and counted in ``queue_dropped``."""
        if not self.accepts(device, message):
            return
        if self.batch_s <= 0:
            self._post(self._feed_posted, (device, t_recv_ns, message))
        elif len(self._batch) >= self._batch_max:  # the worker behind by a whole queue
            self._count_dropped()
        else:
            self._batch.append((device, t_recv_ns, message))
            self._queue_batch()

    def _queue_batch(self) -> None:
        """Queue the call that takes the batch, unless one is queued (two threads may both
        queue one: the second finds the batch empty or small)."""
        if not self._batch_queued:
            self._batch_queued = True
            self._post(self._take_batch, ())

    def _take_batch(self) -> None:
        time.sleep(self.batch_s)
        self._batch_queued = False  # before taking: what comes from now on queues the next
        samples = self._samples
        while samples:
            self.handle_sample(*samples.popleft())
        self.feed_batch(self._batch)

    @hook
    def feed_batch(self, batch: deque[tuple[str, int, object]]) -> None:
        """Take every posted (device, receive stamp ns, message) of ``batch`` (popped from its
        left, where the listeners append: each message once) on the worker: a subclass that
        writes a batch in one pass overrides it."""
        while batch:
            self._feed_posted(*batch.popleft())

    def _feed_posted(self, device: str, t_recv_ns: int, message: object) -> None:
        """A posted message on the worker: its stamp moves the stage's clock (in-process, from
        a trusted source: never refused), then :meth:`feed`."""
        self._stamps.accept(t_recv_ns)
        self.feed(device, t_recv_ns, message)

    def post_odometry(self, o: Odometry) -> None:
        """:meth:`feed_odometry` on the worker thread (after :meth:`start`): returns at once."""
        self._post(self._odometry_posted, (o,))

    def _odometry_posted(self, o: Odometry) -> None:
        self._stamps.accept(round(o.t * 1e9))  # the odometry's time is on the stamp clock
        self.feed_odometry(o)

    def _post(self, fn: Callable[..., object], args: tuple[object, ...]) -> None:
        if not self.worker_started:
            raise RuntimeError(f"{type(self).__name__}.post needs start() (or call feed)")
        self._enqueue(fn, args)

    def _enqueue(self, fn: Callable[..., object], args: tuple[object, ...]) -> None:
        if not self.submit((fn, args)):
            self._count_dropped()

    def _count_dropped(self) -> None:
        with self._drop_lock:
            self.stats.queue_dropped += 1

    # -- outputs and status ---------------------------------------------------------------------
    def publish(self, what: str, payload: bytes, encoding: zenoh.Encoding, t_ns: int) -> None:
        """Put ``payload`` on output ``what`` (when started) and hand it to ``on_publish``."""
        pub = self._pubs.get(what)
        if pub is not None:
            try:
                pub.put(payload, encoding=encoding)
            except zenoh.ZError as exc:
                log.warning("%s: cannot publish %s: %s", self.name, self.key(what), exc)
        if self.on_publish is not None:
            self.on_publish(self.key(what), payload, t_ns)

    def publish_json(self, what: str, body: Mapping[str, object], t: float, schema: str) -> None:
        """Publish ``body`` as JSON (type ``schema``) on output ``what``; ``t``: its time, s."""
        self.publish(what, json.dumps(body).encode(), json_encoding(schema), int(t * 1e9))

    def publish_message(self, what: str, msg: object, t: float) -> None:
        """Publish a declared message (:mod:`auvgw.slam.outputs`) on output ``what`` as an
        envelope, like the sensors' (device: the stage's component); ``t``: its time, s."""
        with self._drop_lock:
            self._seq += 1
            seq = self._seq
        t_ns = int(t * 1e9)
        payload, enc = encode_envelope(msg, self.component, t_ns, seq)
        self.publish(what, payload, enc, t_ns)

    def counters(self) -> dict[str, Any]:
        """Every counter, JSON-ready: the common fields (``stopped``: the last status, sent at
        :meth:`stop` after everything else the stage published; ``t_stamp_ns``: the stage's
        clock, the newest input stamp it took from the bus or :meth:`post`, None before any:
        the vehicle time a viewer puts the status at), then :meth:`status_fields`."""
        with self._lock:
            return {
                "v": SCHEMA_VERSION,
                "component": self.component,
                "vehicle": self.keys.vehicle,
                "t_ns": time.time_ns(),
                "t_stamp_ns": self._stamps.clock_ns,
                "stopped": self._stopped,
                "stage": asdict(self.stats),
                **self.status_fields(),
            }

    def publish_status(self) -> None:
        """Put :meth:`counters` on the status key (every ``status_period_s`` and at stop), then
        :meth:`on_status`."""
        if self._status_pub is not None and self.status_schema is not None:
            with contextlib.suppress(zenoh.ZError):
                self._status_pub.put(json.dumps(self.counters()).encode(),
                                     encoding=json_encoding(self.status_schema))  # fmt: skip
        self.on_status()

    def _answer_status(self, query: zenoh.Query) -> None:
        assert self.status_schema is not None
        query.reply(self.keys.status(self.component), json.dumps(self.counters()).encode(),
                    encoding=json_encoding(self.status_schema))  # fmt: skip

    # -- on the bus -----------------------------------------------------------------------------
    def start(self, subscribe: bool = True) -> None:
        """Declare the outputs, the status publisher and queryable, start the worker and, with
        ``subscribe``, the subscriptions; the liveliness token last. ``subscribe=False`` is for
        a stage fed in-process that still publishes on the bus."""
        if self.session is None:
            raise RuntimeError(f"{type(self).__name__}.start needs a Zenoh session "
                               "(in-process: use feed)")  # fmt: skip
        if self._started:
            return
        self._started = True
        s = self.session
        for what in self.outputs:
            prio = zenoh.Priority.DATA_LOW if what in self.bulk_outputs else zenoh.Priority.DATA
            self._pubs[what] = s.declare_publisher(self.key(what), congestion_control=DROP,
                                                   priority=prio)  # fmt: skip
        status_key = self.keys.status(self.component)
        if self.status_schema is not None:
            self._status_pub = s.declare_publisher(status_key, congestion_control=DROP)
            self._decls.append(s.declare_queryable(status_key, self._answer_status))
        self.start_worker()
        self.on_start(subscribe)
        if subscribe:
            self.subscribe()
        if self.status_schema is not None:
            # declarations travel in order: once this token is seen, the subscriptions are in place
            self._decls.append(s.liveliness().declare_token(self.keys.alive(self.component)))

    def subscribe(self) -> None:
        """Subscribe to :meth:`input_keys` on the session, each callback run in Zenoh's
        receiving thread (``indirect=False``: by default each subscription has a thread of its
        own, and two subscriptions' samples would reach the queue in any relative order). The
        callback only matches the key and queues the payload (never blocking)."""
        assert self.session is not None
        for key in self.input_keys():
            handler = zenoh.handlers.Callback(self._on_sample, indirect=False)
            self._decls.append(self.session.declare_subscriber(key, handler))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if not self.wanted(key):
            return
        item = (key, sample.payload.to_bytes(), time.time_ns())
        if self.batch_s <= 0:
            self._enqueue(self.handle_sample, item)
        elif len(self._samples) >= self._batch_max:  # the worker behind by a whole queue
            self._count_dropped()
        else:
            self._samples.append(item)
            self._queue_batch()

    def _work_item(self, item: _Item) -> None:
        fn, args = item
        fn(*args)

    def _work_describe(self, item: _Item) -> str:
        return f"{self.name}: {getattr(item[0], '__name__', item[0])}"

    def _work_tick(self) -> None:
        self.publish_status()

    def handle_sample(self, key: str, payload: bytes, t_arrival_ns: int | None = None) -> object:
        """One bus payload (the worker's call for each queued sample; tests and replays call it
        directly): :meth:`read_payload`, whose result it returns; what that raises is counted
        (``bad_payloads``) and logged, never raised. ``t_arrival_ns``: host arrival time."""
        try:
            return self.read_payload(key, payload, t_arrival_ns)
        except Exception as exc:  # one bad message must not stop the stage
            self._bad_payload(key, exc, exc_info=True)
            return None

    def _bad_payload(self, key: str, exc: BaseException, exc_info: bool = False) -> None:
        with self._lock:
            log_bad_payload(self.name, key, exc, self.stats.bad_payloads, exc_info)
            self.stats.bad_payloads += 1

    def stop(
        self, flush: bool = True, timeout_s: float = 5.0, drain_limit_s: float | None = None
    ) -> None:
        """:meth:`on_stop`, withdraw the subscriptions, drain the queue (on the worker for as
        long as it makes progress, ``timeout_s`` without any gives up on it, ``drain_limit_s``
        in all at most, None: no limit, after which what is still queued is dropped and counted
        in ``queue_dropped``; without a worker on the calling thread), :meth:`flush`
        (``flush``), publish a last status and withdraw every other declaration (the last
        declared first). Safe to call more than once."""
        if self._stopped:
            return
        self._stopped = True
        self.on_stop()
        undeclare(d for d in self._decls if isinstance(d, zenoh.Subscriber))
        self.stop_worker(timeout_s, drain_limit_s)
        with self._drop_lock:  # what the drain's limit left unhandled: in the last status
            self.stats.queue_dropped += self.worker_discarded
        if flush:
            self.flush()
        self.publish_status()
        undeclare(d for d in reversed(self._decls) if not isinstance(d, zenoh.Subscriber))
        undeclare(self._pubs.values())
        undeclare([self._status_pub] if self._status_pub is not None else [])
        self._pubs.clear()
        self._status_pub = None

    def __enter__(self) -> Stage:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class PipelineStage(Stage):
    """A SLAM pipeline stage (bathymetric, magnetic): output ``what`` on
    ``auv/<v>/slam/<name>/<what>`` (a declared message, :meth:`Stage.publish_message`), status
    (``<Name>Status``) and liveliness as ``slam-<name>``, every decoded bus message counted as
    ``received``.

    ``config``: the stage's settings (kept as ``self.config``); ``session``: publish on it
    (None: in-process only); ``on_publish(key, payload, t_ns)`` is called at every
    publication. A subclass names its counters in :attr:`stats_type` and builds its own state
    in :meth:`setup`."""

    #: the status JSON type is this prefix + ``Status`` (``<Name>``)
    schema_prefix: ClassVar[str] = ""
    #: the stage's counters, made at construction
    stats_type: ClassVar[type[BusCounters]] = BusCounters

    def __init_subclass__(cls, **kw: object) -> None:
        super().__init_subclass__(**kw)
        cls.schema_prefix = cls.name.capitalize()
        cls.status_schema = f"{cls.schema_prefix}Status"

    def __init__(
        self,
        config: StageConfig,
        session: zenoh.Session | None = None,
        on_publish: OnPublish | None = None,
    ) -> None:
        self.config = config
        super().__init__(config, self.stats_type(), session, on_publish=on_publish)
        #: published poses: (t s, x, y, heading)
        self.track: list[tuple[float, float, float, float]] = []
        self.setup()

    def setup(self) -> None:
        """The pipeline's own state, from ``self.config`` (the end of construction)."""

    @property
    def component(self) -> str:
        """``slam-<name>``."""
        return f"slam-{self.name}"

    def key(self, what: str) -> str:
        """``auv/<v>/slam/<name>/<what>``."""
        return self.keys.slam(self.name, what)

    def dispatch(self, env: Envelope, message: object) -> None:
        """One decoded bus message (counted as received)."""
        with self._lock:
            self.stats.received += 1
        super().dispatch(env, message)

    #: one bus payload: decoded, dispatched; a malformed one is counted and logged
    handle = Stage.handle_sample
