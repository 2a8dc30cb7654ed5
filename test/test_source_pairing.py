"""The lease on an input (`loop.source_pairing`), on a hand-driven clock: the first source takes it, the others are
refused and counted, the holder renews it, it expires, it is released and handed over; the publication streams
told apart by their sequence numbers.
"""

import pytest

from robotino_geom_mpc.loop.source_pairing import PublicationStreams, SourcePairing

pytestmark = pytest.mark.unit

MS = 1_000_000
A, B, C = b"a", b"b", b"c"


def test_the_first_source_takes_the_lease_and_the_others_are_refused_and_counted_per_source():
    pairing = SourcePairing(500 * MS)
    assert pairing.admit(A, 0)
    assert [pairing.admit(B, t * MS) for t in (1, 2, 3)] == [False, False, False]
    assert not pairing.admit(C, 4 * MS)
    assert pairing.admit(A, 5 * MS)
    assert pairing.holder == A and pairing.refused == {B: 3, C: 1} and pairing.refused_total == 4
    assert pairing.last_refused == C and pairing.handovers == 1


def test_the_holder_renews_the_lease_with_each_message():
    pairing = SourcePairing(100 * MS)
    for t in range(0, 1000, 90):  # each message within the lease of the one before: 1 s held
        assert pairing.admit(A, t * MS)
        assert not pairing.admit(B, t * MS + 1)
    assert pairing.holder == A and pairing.refused[B] == 12


def test_the_lease_expires_after_lease_ns_without_its_holder_then_the_next_source_takes_it():
    pairing = SourcePairing(100 * MS)
    assert pairing.admit(A, 0)
    assert not pairing.admit(B, 100 * MS)  # exactly the lease: still held
    assert pairing.held(100 * MS) and not pairing.held(100 * MS + 1)
    assert pairing.admit(B, 100 * MS + 1)  # expired: B takes it
    assert not pairing.admit(A, 101 * MS)  # and A is the intruder now
    assert pairing.holder == B and pairing.handovers == 2 and pairing.refused == {B: 1, A: 1}


def test_release_hands_the_lease_to_the_next_source_at_once():
    pairing = SourcePairing(10_000 * MS)
    assert pairing.admit(A, 0)
    assert not pairing.admit(B, 1 * MS)
    assert pairing.release() == A and pairing.holder is None and not pairing.held(1 * MS)
    assert pairing.admit(B, 2 * MS)
    assert not pairing.admit(A, 3 * MS)
    assert pairing.release() == B and pairing.release() is None


def test_a_lease_must_be_positive():
    with pytest.raises(ValueError, match="positive"):
        SourcePairing(0)


def test_streams_of_two_writers_are_told_apart_by_their_numbers_also_with_losses():
    streams = PublicationStreams(window=50)
    first = [streams.source(n) for n in range(1, 601)]  # writer 1 alone
    assert set(first) == {first[0]}
    # writer 2 starts at 1 while writer 1 goes on (interleaved; writer 1 loses every fifth sample)
    seen = []
    for k in range(1, 400):
        if k % 5:
            seen.append((1, streams.source(600 + k)))
        seen.append((2, streams.source(k)))
    ids = {writer: {s for w, s in seen if w == writer} for writer in (1, 2)}
    assert ids[1] == {first[0]} and len(ids[2]) == 1 and ids[1] != ids[2]


def test_a_restarted_writer_and_a_number_far_ahead_start_new_streams():
    streams = PublicationStreams(window=10)
    a = streams.source(100)
    assert streams.source(105) == a
    assert streams.source(1) != a  # a writer that starts over is another writer
    assert streams.source(200) not in (a,)
    assert streams.source(None) == streams.source(None) == b"-"


def test_streams_beyond_forget_drop_the_least_recently_seen():
    streams = PublicationStreams(window=5, forget=2)
    a = streams.source(100)
    b = streams.source(1000)
    assert streams.source(101) == a  # a seen last now
    c = streams.source(5000)  # b is forgotten
    assert streams.source(1001) not in (a, b, c)


def test_a_restarted_writer_counting_up_through_a_dead_writers_last_number_stays_itself():
    """A controller SIGKILLed at sample 520 and restarted: its new samples 1, 2, ... pass 520."""
    streams = PublicationStreams(window=50)
    ms = 1_000_000
    dead = {streams.source(n, n * 10 * ms) for n in range(1, 521)}
    restart_ns = 520 * 10 * ms + 300 * ms  # 0.3 s later: the dead stream is still remembered
    alive = {streams.source(n, restart_ns + n * 10 * ms) for n in range(1, 700)}
    assert len(dead) == 1 and len(alive) == 1 and dead != alive
    # restarted 3 s after, with a loss right across the dead stream's last number: the dead stream was forgotten
    # (not heard for stale_ns); remembered, it would have taken the samples from 522 on
    for stale_s, identities in ((2.0, 1), (10.0, 2)):
        streams = PublicationStreams(window=50, stale_ns=round(stale_s * 1e9))
        first = {streams.source(n, n * 10 * ms) for n in range(1, 521)}
        later = [streams.source(n, 8_200 * ms + n * 10 * ms) for n in (*range(1, 519), *range(522, 600))]
        assert len(set(later)) == identities and first not in ({s} for s in later[:518])


def test_a_tie_between_two_streams_goes_to_the_one_heard_last():
    streams = PublicationStreams(window=50)
    a = streams.source(10, 0)
    b = streams.source(5, 1)
    assert streams.source(10, 2) == b  # b continues from 5 to 10: both streams' last is 10 now
    assert streams.source(11, 3) == b  # the tie goes to b, heard last
    assert streams.source(11, 4) == a  # and a's 11 is a's (b is at 11 already)
