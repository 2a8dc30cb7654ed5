"""One source at a time: a lease on an input topic (commands on the robot side, previews at the controller).

Two controllers on one ROS domain both command one robot, two trajectory nodes both feed one controller: the
receiver would apply whichever message came last. `SourcePairing` pairs the receiver with one source and refuses
the others:

* the first source after the start, or after `SourcePairing.release`, takes the lease;
* each message of the paired source renews it;
* a message of another source while the lease holds is refused and counted per source (the receiver's state is
  not touched: it goes on with its paired source);
* the lease expires after ``lease_ns`` without a message of its holder; the next source then takes it.

A source is any bytes that tell publishers apart. This rclpy (Jazzy, 7.1) gives no publisher GID with a message
(its message info holds the timestamps and the sequence numbers only), so the nodes tell the publishers of a topic
apart by their DDS writers' sequence numbers (`PublicationStreams`): each writer numbers its samples 1, 2, 3, ...
on its own, so a message continues the stream whose last number lies just below its own (within
``window``: the samples a lossy link may lose in a row; of two such streams the closer, then the one heard last),
and any other number starts a new stream (a new writer, or a restarted one). A stream not heard for ``stale_ns`` is
forgotten (a writer that died: a restarted one counting up through its last number stays itself). Two live writers
whose numbers run within ``window`` of each other's (started within ``window`` messages of each other at the same
rate) may be told apart wrongly.
"""

from __future__ import annotations

__all__ = ["PublicationStreams", "SourcePairing"]


class SourcePairing:
    """The lease on one input (module docstring).

    Parameters
    ----------
    lease_ns
        How long the lease holds without a message of its holder [ns] (a positive number).
    """

    def __init__(self, lease_ns: int) -> None:
        if lease_ns <= 0:
            raise ValueError(f"lease_ns must be positive, not {lease_ns}")
        self.lease_ns = lease_ns
        self.holder: bytes | None = None
        self.renewed_ns = 0  # the holder's last message [ns]
        self.refused: dict[bytes, int] = {}  # messages refused per source since the start
        self.last_refused: bytes | None = None
        self.handovers = 0  # leases taken (the first included)

    def set_lease(self, lease_s: float) -> None:
        """A new lease [s] (a positive number; the lease held goes on under it)."""
        self.lease_ns = max(1, round(lease_s * 1e9))

    @property
    def refused_total(self) -> int:
        """Every message refused so far."""
        return sum(self.refused.values())

    def admit(self, source: bytes, now_ns: int) -> bool:
        """Whether the message of `source` at `now_ns` is taken (module docstring); a refusal is counted."""
        if source != self.holder and (self.holder is None or now_ns - self.renewed_ns > self.lease_ns):
            self.holder = source
            self.handovers += 1
        if source == self.holder:
            self.renewed_ns = now_ns
            return True
        self.refused[source] = self.refused.get(source, 0) + 1
        self.last_refused = source
        return False

    def held(self, now_ns: int) -> bool:
        """Whether a source holds the lease at `now_ns`."""
        return self.holder is not None and now_ns - self.renewed_ns <= self.lease_ns

    def release(self) -> bytes | None:
        """Release the lease (``~/release``): the next source to send takes it; the holder released, or None."""
        holder, self.holder = self.holder, None
        return holder


class PublicationStreams:
    """The writers of one topic told apart by their samples' sequence numbers (module docstring).

    Parameters
    ----------
    window
        The largest step from a stream's last number to its next (lost samples in a row + 1).
    forget
        Streams kept at most (the least recently heard is forgotten beyond).
    stale_ns
        A stream not heard for this long is forgotten [ns] (longer than any lease it may hold).
    """

    def __init__(self, window: int = 50, forget: int = 16, stale_ns: int = 2_000_000_000) -> None:
        self.window, self.forget, self.stale_ns = window, forget, stale_ns
        self.last: dict[bytes, tuple[int, int]] = {}  # stream -> its last number, heard at [ns]; least recent first
        self.created = 0

    def source(self, sequence: int | None, now_ns: int = 0) -> bytes:
        """The stream a message numbered `sequence` heard at `now_ns` belongs to (None, no number given: one
        stream for all).
        """
        if sequence is None:
            return b"-"
        while self.last and now_ns - next(iter(self.last.values()))[1] > self.stale_ns:
            del self.last[next(iter(self.last))]
        best: bytes | None = None
        best_last = 0
        for stream, (last, _) in self.last.items():  # least recently heard first: a tie goes to the later
            if last < sequence <= last + self.window and (best is None or last >= best_last):
                best, best_last = stream, last
        if best is None:
            self.created += 1
            best = f"writer-{self.created}".encode()
            if len(self.last) >= self.forget:
                del self.last[next(iter(self.last))]
        self.last.pop(best, None)
        self.last[best] = (sequence, now_ns)
        return best
