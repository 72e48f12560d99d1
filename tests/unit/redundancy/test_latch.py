"""The latch's rule (`gateway.redundancy.latch`): a box asked to be active that hears another
master's requests for `LATCH_S` while it listens gives the virtual address up, stays so while
that master is heard (whatever its role by then), and is fit again once none has been heard for
`silence_s`. Times are the role machine's monotonic seconds, fed as a line would have them."""

from __future__ import annotations

from gateway.redundancy.latch import LATCH_S, RETRY_S, SplitLatch

SILENCE_S = 1.0
POLL_S = 0.2
"""The other master's polls, five a second."""


def polls(latch: SplitLatch, start: float, end: float) -> None:
    """The other master's requests heard every `POLL_S` from `start` up to `end`."""
    count = round((end - start) / POLL_S)
    for step in range(count + 1):
        latch.heard(round(start + step * POLL_S, 6))


def test_heard_while_asked_active_latches_after_the_bound_and_not_before() -> None:
    latch = SplitLatch(SILENCE_S)
    listening_since = 10.0  # asked active at 10 s; the other master polls from 9 s on
    polls(latch, 9.0, 10.0 + LATCH_S - 0.2)
    assert latch.look(10.0 + LATCH_S - 0.2, listening_since) is None
    assert not latch.latched
    polls(latch, 10.0 + LATCH_S, 10.0 + LATCH_S)
    # Counted from the listening's start, not from the first request heard (a standby hears
    # the active all the time).
    assert latch.look(10.0 + LATCH_S, listening_since) is True
    assert latch.latched
    assert latch.hearing_for(10.0 + LATCH_S) == 1.0 + LATCH_S


def test_still_heard_as_standby_the_latch_holds_and_a_silent_line_clears_it() -> None:
    latch = SplitLatch(SILENCE_S)
    polls(latch, 0.0, LATCH_S)
    assert latch.look(LATCH_S, 0.0) is True
    # Keepalived FAULT, its notify asks `role standby`: no longer listening, still hearing.
    polls(latch, LATCH_S + POLL_S, 60.0)
    for at in (LATCH_S + 1.0, 30.0, 60.0):
        assert latch.look(at, None) is None
        assert latch.latched
    # The other master gone: its last request at 60 s, the line silent since.
    assert latch.look(60.0 + SILENCE_S - 0.01, None) is None
    assert latch.latched
    assert latch.look(60.0 + SILENCE_S, None) is False
    assert not latch.latched
    assert latch.hearing_for(60.0 + SILENCE_S) is None


def test_waiting_out_the_silence_or_a_short_overlap_never_latches() -> None:
    latch = SplitLatch(SILENCE_S)
    # Asked active on a silent line (the other box dead): nothing heard, however long.
    assert latch.look(100.0, 0.0) is None
    # The old master's last polls heard for a second after the ask (its notify on its way),
    # then silence: a takeover, not a cut.
    polls(latch, 200.0, 201.0)
    for at in (201.0, 201.5, 202.0, 210.0):
        assert latch.look(at, 200.0) is None
    assert not latch.latched


def test_a_standby_hearing_the_active_never_latches() -> None:
    latch = SplitLatch(SILENCE_S)
    polls(latch, 0.0, 30.0)
    assert latch.look(30.0, None) is None
    assert not latch.latched
    assert latch.hearing_for(30.0) == 30.0


def test_a_silence_between_two_masters_starts_the_count_again() -> None:
    latch = SplitLatch(SILENCE_S)
    polls(latch, 0.0, 2.0)
    polls(latch, 2.0 + SILENCE_S + 0.2, 2.0 + SILENCE_S + 0.2 + LATCH_S - 0.4)
    # Listening since 0 s, but the master heard now started after a silence: not yet.
    assert latch.look(2.0 + SILENCE_S + LATCH_S - 0.2, 0.0) is None
    assert not latch.latched


def test_held_for_a_minute_the_latch_is_let_go_on_trial_and_a_standby_stays_fit() -> None:
    """Once the link is back the latched box would stay FAULT while the other master polls:
    it is let go every `RETRY_S`. A healed link keeps it BACKUP (asked standby: it stays fit);
    a cut that goes on makes it MASTER again, asked active, and it latches again."""
    latch = SplitLatch(SILENCE_S)
    polls(latch, 0.0, LATCH_S)
    assert latch.look(LATCH_S, 0.0) is True
    polls(latch, LATCH_S + POLL_S, LATCH_S + RETRY_S + 30.0)
    assert latch.look(LATCH_S + RETRY_S - 0.01, None) is None
    assert latch.latched
    assert latch.look(LATCH_S + RETRY_S, None) is False
    assert not latch.latched
    assert latch.on_trial  # another master still heard: a trial, not the other's end
    # The link healed: Keepalived BACKUP, the box asked standby, hearing the active as always.
    for at in (LATCH_S + RETRY_S + 1.0, LATCH_S + RETRY_S + 29.0):
        assert latch.look(at, None) is None
        assert not latch.latched
    # The cut goes on instead: MASTER again 1.5 s after the trial, asked active, latched again.
    asked = LATCH_S + RETRY_S + 1.5
    assert latch.look(asked + LATCH_S - 0.1, asked) is None
    assert latch.look(asked + LATCH_S, asked) is True
    assert latch.latched
