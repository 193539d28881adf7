"""The daemon's delivery core (`gazehdr.drivers.delivery.Delivery`) with scripted inputs: no
sockets, no sleeps, no threads. Each test plays the source, the clock and the server."""

from __future__ import annotations

import math
from typing import Any

import pytest

from gazehdr.drivers import wire
from gazehdr.drivers.delivery import DaemonError, Delivery, State
from gazehdr.drivers.ratelimit import TokenBucket
from gazehdr.drivers.samples import GazeSample
from gazehdr.drivers.sessionlog import ClockUpdate, FixationPlace, GazeEvent, Note
from gazehdr.drivers.sources import SourceInfo
from gazehdr.drivers.states import InvalidStateError

MS = 1_000_000  # ns
S = 1_000_000_000


def _core(*, live: bool = True, has_events: bool = False, **options: Any) -> Delivery:
    options.setdefault("detector", None)  # only what the test adds is sent
    return Delivery(SourceInfo("rig", live=live, has_events=has_events), **options)


def _samples(times: range) -> list[GazeSample]:
    return [GazeSample(t * MS, 960.0, 540.0) for t in times]


def _connected(core: Delivery) -> Delivery:
    core.hello()
    assert core.welcome(wire.dumps(wire.Welcome(wire.PROTOCOL)))
    core.connected()
    return core


def _round(core: Delivery, now_ns: int) -> tuple[list[wire.Message], wire.Echo | None]:
    """One sending round at `now_ns`, as the server would read it."""
    messages = [wire.parse(text) for text in core.send(now_ns)]
    echo = core.echo(now_ns)
    return messages, wire.parse(echo) if echo is not None else None


def _sample_ms(messages: list[wire.Message]) -> list[int]:
    return [s.t_ns // MS for m in messages if isinstance(m, wire.Samples) for s in m.samples]


def _reply(core: Delivery, echo: wire.Echo, *, server_ns: int, at_ns: int) -> None:
    core.receive(wire.dumps(wire.EchoReply(echo.t0_ns, server_ns)), at_ns)


def test_a_full_buffer_drops_the_oldest_never_sent_item_of_a_live_source() -> None:
    core = _core(buffer=5, has_events=True)
    fixation = GazeEvent("fixation_start", 1, 0, x=100.0, y=100.0)
    for record in [fixation, *_samples(range(1, 9))]:  # 9 items, no server
        core.add(record)
    assert core.unsent == 5
    assert (core.stats.events_dropped, core.stats.samples_dropped) == (1, 3)  # the oldest four
    assert core.warnings() == ["send buffer full (5 items): dropping the oldest"]  # said once
    core.records_to_write()

    _connected(core)
    note = "send buffer full (5 items) while disconnected: dropped 3 samples, 1 events"
    assert core.warnings() == [note]
    assert core.records_to_write() == [Note(8 * MS, note)]  # at the latest sample's time
    messages, _ = _round(core, 0)
    assert _sample_ms(messages) == [4, 5, 6, 7, 8]  # the newest five, in order


def test_a_replay_never_drops_it_makes_the_source_wait() -> None:
    core = _core(buffer=5, live=False)
    for sample in _samples(range(8)):
        core.add(sample)
    assert core.unsent == 8 >= core.buffer  # the daemon's source thread waits on this
    assert core.stats.samples_dropped == 0 and core.warnings() == []
    _connected(core)
    messages, _ = _round(core, 0)
    assert _sample_ms(messages) == list(range(8))


def test_an_echo_acknowledges_exactly_what_was_sent_before_it() -> None:
    core = _connected(_core())
    for sample in _samples(range(3)):
        core.add(sample)
    first, echo1 = _round(core, 1 * MS)
    for sample in _samples(range(3, 5)):
        core.add(sample)
    second, echo2 = _round(core, 2 * MS)
    assert _sample_ms(first) == [0, 1, 2] and _sample_ms(second) == [3, 4]
    assert echo1 is not None and echo2 is not None and core.backlog == 5

    _reply(core, echo1, server_ns=0, at_ns=3 * MS)
    assert core.stats.samples_delivered == 3 and core.backlog == 2
    assert core.send_due  # the window has room again
    core.receive(wire.dumps(wire.EchoReply(12345, 0)), 4 * MS)  # an echo we never sent
    assert core.stats.samples_delivered == 3
    _reply(core, echo2, server_ns=0, at_ns=5 * MS)
    assert core.stats.samples_delivered == 5 and core.backlog == 0
    _reply(core, echo1, server_ns=0, at_ns=6 * MS)  # a repeated reply acknowledges nothing more
    assert core.stats.samples_delivered == 5


def test_a_later_echo_acknowledges_what_an_earlier_lost_one_would_have() -> None:
    core = _connected(_core())
    core.add(_samples(range(1))[0])
    _, echo1 = _round(core, 1 * MS)
    core.add(_samples(range(1, 2))[0])
    _, echo2 = _round(core, 2 * MS)
    _reply(core, echo2, server_ns=0, at_ns=3 * MS)
    assert core.stats.samples_delivered == 2
    _reply(core, echo1, server_ns=0, at_ns=4 * MS)  # its mark went with the later one
    assert core.stats.samples_delivered == 2


def test_the_in_flight_window_holds_back_what_is_not_acknowledged() -> None:
    core = _connected(_core(batch=2, max_inflight=4, has_events=True))
    for sample in _samples(range(4)):
        core.add(sample)
    core.add(GazeEvent("blink_start", 1, 4 * MS))
    for sample in _samples(range(5, 10)):
        core.add(sample)
    messages, echo = _round(core, 0)
    assert _sample_ms(messages) == [0, 1, 2, 3]  # two batches fill the window
    assert _round(core, 1 * MS)[0] == []  # not even the event
    _reply(core, echo, server_ns=0, at_ns=2 * MS)
    messages, _ = _round(core, 3 * MS)
    assert isinstance(messages[0], wire.Event) and _sample_ms(messages) == [5, 6, 7]


def test_what_a_lost_connection_left_unacknowledged_is_sent_first_on_the_next() -> None:
    core = _connected(_core())
    for sample in _samples(range(4)):
        core.add(sample)
    _, old_echo = _round(core, 1 * MS)
    core.connection_lost()
    assert core.stats.resent == 4 and core.stats.disconnects == 1
    for sample in _samples(range(4, 6)):
        core.add(sample)  # while disconnected

    _connected(core)
    assert core.stats.connects == 2
    _reply(core, old_echo, server_ns=0, at_ns=2 * MS)  # from the old connection: no proof
    assert core.stats.samples_delivered == 0
    messages, echo = _round(core, 3 * MS)
    assert [_sample_ms([m]) for m in messages] == [[0, 1, 2, 3], [4, 5]]  # resent, then new
    _reply(core, echo, server_ns=0, at_ns=4 * MS)
    assert core.stats.samples_delivered == 6 and core.backlog == 0
    assert core.stats.samples_sent == 10  # resends included


def test_pacing_keeps_to_the_rate_and_the_burst() -> None:
    core = _connected(_core(max_rate=64.0, burst=10.0, max_inflight=1000, has_events=True))
    for sample in _samples(range(200)):
        core.add(sample)
    sent = [len(_sample_ms(_round(core, 0)[0]))]  # a full bucket: the burst
    assert not core.send_due  # the bucket is empty: no round before flush_interval
    core.add(GazeEvent("blink_start", 1, 300 * MS))  # an event would wake it, not now
    assert not core.send_due
    times = [0.0, 1 / 16, 5 / 64, 7 / 64, 2.0]  # seconds that floats hold exactly
    for now in times[1:]:
        sent.append(len(_sample_ms(_round(core, round(now * S))[0])))
    # 64/s: 4 in 1/16 s, 1 in 1/64 s, 2 in 2/64 s; after 1.9 s idle, the burst again, not 121
    assert sent == [10, 4, 1, 2, 10]
    assert list(core.stats.sent_times) == list(zip(times, sent, strict=True))


def test_a_reconnect_starts_with_a_full_bucket() -> None:
    core = _connected(_core(max_rate=100.0, burst=10.0, batch=50, max_inflight=1000))
    for sample in _samples(range(30)):
        core.add(sample)
    assert len(_sample_ms(_round(core, 0)[0])) == 10
    core.connection_lost()
    _connected(core)
    assert len(_sample_ms(_round(core, 1 * MS)[0])) == 10  # not 0: a new server's own limit


def test_the_token_bucket_is_told_the_time() -> None:
    bucket = TokenBucket(rate=2000.0, burst=4000.0)  # the server's sample limit
    assert bucket.admit(5000, 100.0) == 4000  # starts full
    assert bucket.admit(5000, 100.5) == 1000  # half a second at 2000/s
    assert bucket.admit(10, 100.5) == 0
    assert bucket.admit(10_000, 1000.0) == 4000  # never more than the burst
    with pytest.raises(ValueError):
        TokenBucket(rate=0.0, burst=10.0)


def test_the_clock_estimate_keeps_the_smallest_round_trip_and_resets_on_reconnect() -> None:
    core = _connected(_core(clock_window=3))
    offset = 7 * S  # the server's clock is 7 s ahead

    def echo_with_rtt(now_ns: int, rtt_ns: int) -> None:
        _, echo = _round(core, now_ns)
        assert echo is not None and echo.t0_ns == now_ns
        _reply(core, echo, server_ns=now_ns + rtt_ns // 2 + offset, at_ns=now_ns + rtt_ns)

    echo_with_rtt(1 * S, 4 * MS)
    echo_with_rtt(3 * S, 1 * MS)  # the best
    echo_with_rtt(5 * S, 3 * MS)
    clock = core.stats.clock
    assert (clock.rtt_ns, clock.offset_ns, clock.uncertainty_ns) == (1 * MS, offset, MS // 2)
    echo_with_rtt(7 * S, 5 * MS)
    echo_with_rtt(9 * S, 6 * MS)  # the 1 ms one slid out of the window of 3
    assert core.stats.clock.rtt_ns == 3 * MS
    # a live source's log gets the estimate when it changes, at most once a second
    clocks = [r for r in core.records_to_write() if isinstance(r, ClockUpdate)]
    assert [(c.t_ns, c.offset_uncertainty_ns) for c in clocks] == [
        (1 * S + 4 * MS, 2 * MS),
        (3 * S + 1 * MS, MS // 2),
        (9 * S + 6 * MS, 3 * MS // 2),
    ]

    core.connection_lost()
    _connected(core)  # maybe a rebooted server: the old echoes say nothing of its clock
    offset = -2 * S
    echo_with_rtt(11 * S, 20 * MS)
    assert core.stats.clock.rtt_ns == 20 * MS and core.stats.clock.offset_ns == offset


def test_a_replay_records_no_clock() -> None:
    core = _connected(_core(live=False))
    _, echo = _round(core, 1 * S)
    _reply(core, echo, server_ns=5 * S, at_ns=1 * S + MS)
    assert core.stats.clock is not None and core.records_to_write() == []


def test_echo_cadence() -> None:
    core = _connected(_core(echo_interval=1.0))
    assert _round(core, 0)[1] is not None  # the first round of a connection
    assert _round(core, 500 * MS)[1] is None  # idle: one a second
    assert _round(core, 1001 * MS)[1] is not None
    core.add(_samples(range(1))[0])
    assert _round(core, 1002 * MS)[1] is not None  # after whatever was sent
    assert _round(core, 1050 * MS)[1] is None
    assert _round(core, 1103 * MS)[1] is not None  # in flight: every 0.1 s
    # two echoes at one clock reading still name distinct marks
    core.add(_samples(range(1, 2))[0])
    _, a = _round(core, 1103 * MS)
    assert a is not None and a.t0_ns == 1103 * MS + 1


def test_what_the_server_would_refuse_is_counted_not_sent() -> None:
    core = _connected(_core(has_events=True, places={(2, None): FixationPlace(3 * MS, 4.0, 5.0)}))
    for t in (-2, -1, 0, 1):
        core.add(GazeSample(t * MS, 960.0, 540.0))
    core.add(GazeEvent("fixation_start", 1, 2 * MS))  # no position, no place
    core.add(GazeEvent("fixation_start", 2, 3 * MS))  # no position, its place known
    messages, _ = _round(core, 0)
    assert _sample_ms(messages) == [0, 1]
    events = [m for m in messages if isinstance(m, wire.Event)]
    assert [(e.id, e.x * 1920, e.y * 1080) for e in events] == [(2, 4.0, 5.0)]
    assert (core.stats.samples_unsendable, core.stats.events_unsendable) == (2, 1)
    assert len(core.warnings()) == 1  # said once
    assert [r.t_ns for r in core.records_to_write()][:4] == [-2 * MS, -MS, 0, MS]  # recorded


def test_the_servers_rate_limit_notes_are_added_up() -> None:
    core = _connected(_core())
    for n, unit in [(12, "samples"), (3, "echoes"), (30, "samples")]:
        text = f"rate limit: {n} {unit} dropped; at most 2000 {unit}/s are accepted"
        core.receive(wire.dumps(wire.Notice(text)), 0)
    core.receive(wire.dumps(wire.Notice("hello: this connection has said hello already")), 0)
    assert core.stats.server_rate_limited == {"samples": 42, "echoes": 3}
    assert "the server's rate limits dropped 3 echoes, 42 samples" in core.stats.summary()
    core.receive("{not json", 0)
    warnings = core.warnings()
    assert len(warnings) == 5 and warnings[3].startswith("server: hello:")
    assert warnings[4].startswith("ignoring a reply from the server:")


def test_an_event_makes_a_round_due_sooner_than_samples() -> None:
    core = _connected(_core(has_events=True, batch=3))
    _round(core, 0)
    for sample in _samples(range(2)):
        core.add(sample)
    assert not core.send_due  # a batch not yet full waits for flush_interval
    core.add(GazeEvent("fixation_start", 1, 2 * MS, x=1.0, y=2.0))
    assert core.send_due
    _round(core, MS)
    for sample in _samples(range(3, 5)):
        core.add(sample)
    assert not core.send_due
    core.add(_samples(range(5, 6))[0])  # the batch is full
    assert core.send_due


def test_the_end_of_the_source_flushes_the_detector_and_drains() -> None:
    core = _connected(_core(detector="ivt"))
    for i in range(200):  # 200 ms still: a fixation the detector has not ended
        core.add(GazeSample(i * MS, 500.0, 500.0))
    detected = core.stats.events_produced
    core.end_of_source()
    assert core.stats.events_produced > detected and core.send_due and not core.drained
    core.add(GazeSample(300 * MS, 500.0, 500.0))  # too late: not taken
    assert core.stats.samples_produced == 200
    while not core.drained:
        _, echo = _round(core, 400 * MS)
        _reply(core, echo, server_ns=0, at_ns=401 * MS)
    assert core.stats.samples_delivered == 200
    assert core.stats.events_delivered == core.stats.events_produced


def test_what_is_left_at_the_end_is_counted_undelivered() -> None:
    core = _core(buffer=3)
    for sample in _samples(range(5)):
        core.add(sample)
    core.records_to_write()
    core.warnings()
    core.finish()
    assert (core.stats.samples_undelivered, core.stats.samples_dropped) == (3, 2)
    assert core.backlog == 0 and core.drained
    warnings = core.warnings()
    assert warnings[0].startswith("gave up: 3 samples and 0 events were never delivered")
    assert warnings[1].endswith("before the end: dropped 2 samples, 0 events")
    assert [type(r) for r in core.records_to_write()] == [Note]


def test_hello_and_welcome() -> None:
    core = _core()
    hello = wire.parse(core.hello())
    assert isinstance(hello, wire.Hello) and hello.tracker == "rig"
    assert hello.screen["screen_width_px"] == 1920.0
    assert not core.welcome(wire.dumps(wire.EchoReply(1, 2)))  # not yet
    with pytest.raises(DaemonError, match="refused hello: no"):
        core.welcome(wire.dumps(wire.Notice("no")))
    with pytest.raises(DaemonError, match="reply to hello"):
        core.welcome("[]")


def test_a_binocular_recording_sends_the_first_fixating_eyes_fixations() -> None:
    core = _connected(_core(has_events=True))
    for kind, eye in [
        ("fixation_start", "right"),
        ("fixation_start", "left"),
        ("blink_start", None),
    ]:
        core.add(GazeEvent(kind, 1, MS, x=1.0, y=1.0, eye=eye))
    sent = [m for m in _round(core, 0)[0] if isinstance(m, wire.Event)]
    assert [m.kind for m in sent] == ["fixation_start", "blink_start"]
    assert core.stats.events_produced == 2
    assert len(core.records_to_write()) == 3  # all recorded
    assert math.isnan(sent[1].x)


# --- the connection's states: each call its state does not allow is refused, losing nothing ---


def _refused(call: Any, method: str, state: State) -> None:
    """`call()` raises InvalidStateError naming the method and the state."""
    with pytest.raises(InvalidStateError, match=rf"^Delivery\.{method}\(\) in state {state.name}:"):
        call()


def test_the_states_of_a_connections_life() -> None:
    """Guards the transitions themselves (mutation: `hello`, `connected`, `connection_lost` or
    `finish` leaving `state` as it was)."""
    core = _core()
    assert core.state is State.IDLE and issubclass(InvalidStateError, RuntimeError)
    core.hello()
    assert core.state is State.CONNECTING
    core.connected()
    assert core.state is State.OPEN
    core.connection_lost()
    assert core.state is State.IDLE
    core.finish()
    assert core.state is State.CLOSED


def test_sending_before_a_connection_is_welcomed_is_refused_and_loses_nothing() -> None:
    """Mutation: no state check in `send` (it would take the buffered samples out for a
    connection that is not there)."""
    core = _core()
    for sample in _samples(range(3)):
        core.add(sample)
    _refused(lambda: core.send(0), "send", State.IDLE)
    core.hello()
    _refused(lambda: core.send(0), "send", State.CONNECTING)
    assert core.unsent == 3 and core.stats.samples_sent == 0 and not core.stats.sent_times
    assert core.records_to_write() == _samples(range(3))  # recorded all the same
    core.welcome(wire.dumps(wire.Welcome(wire.PROTOCOL)))
    core.connected()
    messages, echo = _round(core, MS)
    assert _sample_ms(messages) == [0, 1, 2] and echo is not None


def test_an_echo_before_a_connection_is_welcomed_is_refused() -> None:
    """Mutation: no state check in `echo` (it would mark what no server will acknowledge)."""
    core = _core()
    core.add(_samples(range(1))[0])
    _refused(lambda: core.echo(0), "echo", State.IDLE)
    _connected(core)
    messages, echo = _round(core, MS)
    assert _sample_ms(messages) == [0] and echo is not None and echo.t0_ns == MS
    _reply(core, echo, server_ns=0, at_ns=2 * MS)
    assert core.stats.samples_delivered == 1 and core.backlog == 0


def test_a_reply_without_a_connection_is_refused() -> None:
    """Mutation: no state check in `receive` (a reply of no connection would move the clock
    estimate)."""
    core = _connected(_core())
    core.add(_samples(range(1))[0])
    _, echo = _round(core, MS)
    core.connection_lost()
    late = wire.dumps(wire.EchoReply(echo.t0_ns, 5 * S))
    _refused(lambda: core.receive(late, 2 * MS), "receive", State.IDLE)
    assert core.stats.clock is None and core.stats.samples_delivered == 0
    assert core.backlog == 1 and core.warnings() == []


def test_losing_a_connection_that_never_was_is_refused_and_loses_nothing() -> None:
    """Mutation: no state check in `connection_lost` (it would count a disconnect before any
    connection)."""
    core = _core()
    for sample in _samples(range(5)):
        core.add(sample)
    _refused(core.connection_lost, "connection_lost", State.IDLE)
    assert (core.stats.disconnects, core.stats.resent, core.unsent) == (0, 0, 5)
    messages, _ = _round(_connected(core), MS)
    assert _sample_ms(messages) == [0, 1, 2, 3, 4]


def test_a_connection_is_lost_once() -> None:
    """Mutation: no state check in `connection_lost` (a second call for one loss would count
    a second disconnect)."""
    core = _connected(_core())
    for sample in _samples(range(4)):
        core.add(sample)
    _round(core, MS)
    core.connection_lost()
    _refused(core.connection_lost, "connection_lost", State.IDLE)
    assert (core.stats.disconnects, core.stats.resent, core.backlog) == (1, 4, 4)
    messages, echo = _round(_connected(core), 2 * MS)
    assert _sample_ms(messages) == [0, 1, 2, 3]  # sent again once, in order
    _reply(core, echo, server_ns=0, at_ns=3 * MS)
    assert core.stats.samples_delivered == 4 and core.backlog == 0


def test_a_connection_lost_before_its_welcome_counts_nothing() -> None:
    """A connection may die between hello and welcome: allowed, back to IDLE, and neither a
    disconnect nor a resend. Mutation: `connection_lost` in CONNECTING counting as in OPEN."""
    core = _core()
    core.add(_samples(range(1))[0])
    core.hello()
    core.connection_lost()
    assert core.state is State.IDLE
    assert (core.stats.connects, core.stats.disconnects, core.stats.resent) == (0, 0, 0)
    messages, _ = _round(_connected(core), MS)
    assert _sample_ms(messages) == [0] and core.stats.connects == 1


def test_hello_on_a_connection_already_begun_is_refused() -> None:
    """Mutation: no state check in `hello` (a second hello would take an open connection back
    to CONNECTING, where nothing is sent)."""
    core = _core()
    core.hello()
    _refused(core.hello, "hello", State.CONNECTING)
    assert core.welcome(wire.dumps(wire.Welcome(wire.PROTOCOL)))
    core.connected()
    core.add(_samples(range(1))[0])
    _refused(core.hello, "hello", State.OPEN)
    assert core.state is State.OPEN
    assert _sample_ms(_round(core, MS)[0]) == [0]


def test_a_welcome_without_a_hello_is_refused() -> None:
    """Mutation: no state check in `welcome` (a reply read with no hello given)."""
    core = _core()
    welcome = wire.dumps(wire.Welcome(wire.PROTOCOL))
    _refused(lambda: core.welcome(welcome), "welcome", State.IDLE)
    _connected(core)
    _refused(lambda: core.welcome(welcome), "welcome", State.OPEN)
    assert core.state is State.OPEN


def test_connected_without_a_hello_or_twice_is_refused() -> None:
    """Mutation: no state check in `connected` (a connection counted that said no hello, or
    one counted twice, its clock estimate thrown away)."""
    core = _core()
    _refused(core.connected, "connected", State.IDLE)
    assert core.stats.connects == 0
    _connected(core)
    _, echo = _round(core, S)
    _reply(core, echo, server_ns=2 * S, at_ns=S + 2 * MS)
    _refused(core.connected, "connected", State.OPEN)
    assert core.stats.connects == 1 and core.clock.best is not None


def test_finishing_twice_is_refused_and_counts_once() -> None:
    """Mutation: no state check in `finish` (a second call would say "gave up" again)."""
    core = _core()
    for sample in _samples(range(3)):
        core.add(sample)
    core.finish()
    assert core.stats.samples_undelivered == 3 and len(core.warnings()) == 1
    _refused(core.finish, "finish", State.CLOSED)
    assert core.stats.samples_undelivered == 3 and core.warnings() == []


def test_nothing_is_sent_or_taken_once_finished() -> None:
    """Mutation: `finish` leaving the state OPEN (a round after it would still send, and the
    source's records would still be taken, never to be counted)."""
    core = _connected(_core())
    core.finish()
    core.add(_samples(range(1))[0])  # the source's last record, come late: not taken
    assert core.stats.samples_produced == 0 and not core.accepting and core.drained
    for method, call in [
        ("send", lambda: core.send(0)),
        ("echo", lambda: core.echo(0)),
        ("hello", core.hello),
        ("connection_lost", core.connection_lost),
    ]:
        _refused(call, method, State.CLOSED)
    core.end_of_source()  # the source's end, come late: nothing changes
    assert core.state is State.CLOSED and core.stats.disconnects == 0
