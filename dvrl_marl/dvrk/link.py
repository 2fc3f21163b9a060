"""One UDP link to a dVRK component through the dVRK's socket streamer (``sawSocketStreamer``), and the log of it.

The streamer's protocol, as its sources (release 1.2.0, the dVRK 2.4.0's) have it:

- every datagram is one JSON object whose keys are commands, e.g. ``{"servo_cp": {"Goal": {...}}}``; several keys in
  one datagram are executed in turn; a void command's value is ignored;
- every period the streamer sends one datagram per read command it was configured with (``{"measured_cp": {...}}``)
  and the events as they come (``{"operating_state": {...}}``);
- its receive buffer is 1,024 bytes and it writes a terminator after what it read: a datagram longer than 1,023
  bytes would be cut, so :meth:`StreamerLink.send` refuses one;
- it sends to the ``ip:port`` of its configuration file from a socket it never binds (the system gives it a port
  when it first sends) and takes commands from whoever writes to that socket: the link binds the configured port,
  learns the streamer's address from the datagrams it receives and sends to it from the same socket (nothing can be
  sent before the streamer has been heard).

Every datagram in and out is written to a :class:`DatagramLog` (JSON lines, flushed line by line: a run that is
stopped keeps what it logged) that :class:`ReplayLink` plays back.
"""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

__all__ = ["MAX_DATAGRAM", "DatagramLog", "StreamerLink", "ReplayLink", "read_log"]

#: The longest datagram the streamer reads whole (its 1,024-byte buffer holds a terminator after it).
MAX_DATAGRAM = 1023


class DatagramLog:
    """JSON lines ``{"t": seconds, "link": name, "dir": "in" | "out" | "note", "data": ...}``, each flushed as it is
    written; ``t`` is the clock the links read (monotonic seconds)."""

    def __init__(self, path=None):
        self.path = None if path is None else Path(path)
        self._file = None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = self.path.open("a", encoding="utf-8")
        self.lines = 0

    def write(self, t: float, link: str, direction: str, data) -> None:
        self.lines += 1
        if self._file is not None:
            self._file.write(json.dumps({"t": round(t, 6), "link": link, "dir": direction, "data": data},
                                        separators=(",", ":")) + "\n")
            self._file.flush()

    def note(self, t: float, what: str, **details) -> None:
        """A line of the run's own (a safety stop, a clamped command, the end)."""
        self.write(t, "seat", "note", {"what": what, **details})

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def read_log(path) -> list[dict]:
    """The lines of a :class:`DatagramLog`, in order (a line that is not JSON is an error naming it)."""
    lines = []
    for number, text in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), start=1):
        if not text.strip():
            continue
        try:
            line = json.loads(text)
        except json.JSONDecodeError as error:
            raise ValueError(f"{path}:{number}: not a JSON line ({error.msg})") from None
        if not isinstance(line, dict) or not {"t", "link", "dir", "data"} <= set(line):
            raise ValueError(f"{path}:{number}: a log line needs t, link, dir and data")
        lines.append(line)
    return lines


def encode(payload: dict, who: str) -> bytes:
    """``payload`` as the streamer reads it (compact JSON), refused by name if it would not fit its buffer."""
    if not isinstance(payload, dict) or not payload:
        raise ValueError(f"{who}: a datagram is a non-empty JSON object of commands, got {payload!r}")
    data = json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
    if len(data) > MAX_DATAGRAM:
        raise ValueError(f"{who}: the datagram for {sorted(payload)} is {len(data)} bytes; the streamer reads at most "
                         f"{MAX_DATAGRAM}")
    return data


class StreamerLink:
    """A UDP socket bound to ``local_port`` (the port the streamer's configuration sends to) that answers the
    streamer at the address its datagrams come from: the first one heard (from ``host`` only, when given); datagrams
    from any other address are logged and ignored (a restarted dVRK needs a new link). :meth:`receive` drains what has arrived and keeps the latest value of each key with the time it arrived
    (:attr:`latest`)."""

    def __init__(self, name: str, local_port: int, *, host: str | None = None, log: DatagramLog | None = None,
                 clock=time.monotonic):
        if not isinstance(local_port, int) or isinstance(local_port, bool) or not 0 < local_port < 65536:
            raise ValueError(f"{name}: local_port must be a UDP port in 1..65535, got {local_port!r}")
        self.name, self.host = name, host
        self.address = None  # the streamer's, once heard
        self.log = log or DatagramLog()
        self.clock = clock
        self.latest: dict[str, tuple[float, object]] = {}
        self.sent = 0
        self.received = 0
        self.unreadable = 0
        self.ignored = 0
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._socket.bind(("", local_port))
        except OSError as error:
            self._socket.close()
            raise ValueError(f"{name}: cannot listen on UDP port {local_port}: {error}") from None
        self._socket.setblocking(False)
        self.local_port = local_port

    def send(self, payload: dict) -> None:
        data = encode(payload, self.name)
        if self.address is None:
            raise RuntimeError(f"{self.name}: nothing heard from its streamer yet (its address comes with its "
                               f"datagrams); is it running and sending to this machine's port {self.local_port}?")
        self._socket.sendto(data, self.address)
        self.sent += 1
        self.log.write(self.clock(), self.name, "out", payload)

    def receive(self) -> int:
        """Read every datagram waiting; returns how many. One that is not a JSON object is logged as text and
        skipped."""
        count = 0
        while True:
            try:
                data, sender = self._socket.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return count
            if (self.host is not None and sender[0] != self.host) or (self.address is not None and
                                                                      sender != self.address):
                # Another sender (a second streamer on this port, a restarted dVRK): never mixed with the first one,
                # whose commands would then go to whichever spoke last.
                self.ignored += 1
                self.log.write(self.clock(), self.name, "note", {"what": "ignored", "from": list(sender)})
                continue
            count += 1
            self.address = sender  # (the first streamer heard: it answers from the socket it sends from)
            self._take(data.decode(errors="replace"))

    def _take(self, text: str) -> None:
        now = self.clock()
        try:
            payload = json.loads(text)
        except json.JSONDecodeError:
            payload = None
        if not isinstance(payload, dict):
            self.unreadable += 1
            self.log.write(now, self.name, "in", {"unreadable": text[:MAX_DATAGRAM]})
            return
        self.received += 1
        self.log.write(now, self.name, "in", payload)
        for key, value in payload.items():
            self.latest[key] = (now, value)

    def close(self) -> None:
        self._socket.close()


class ReplayLink:
    """A :class:`StreamerLink` that plays a log's incoming datagrams of one link back by their times (offset so that
    the first plays at the clock's first reading) and keeps what would be sent in :attr:`outbox` (a dry run, a test
    that needs no robot)."""

    def __init__(self, name: str, lines: list[dict], *, clock, link: str | None = None):
        self.name = name
        self.log = DatagramLog()
        self.clock = clock
        self.latest: dict[str, tuple[float, object]] = {}
        self.outbox: list[tuple[float, dict]] = []
        self.sent = self.received = self.unreadable = 0
        incoming = [line for line in lines if line["dir"] == "in" and line["link"] == (link or name)]
        self._start = incoming[0]["t"] if incoming else 0.0
        self._incoming = incoming
        self._next = 0
        self._zero = None

    def send(self, payload: dict) -> None:
        encode(payload, self.name)  # (the same checks as on the wire)
        self.sent += 1
        self.outbox.append((self.clock(), payload))

    def receive(self) -> int:
        now = self.clock()
        if self._zero is None:
            self._zero = now
        count = 0
        while self._next < len(self._incoming) and self._incoming[self._next]["t"] - self._start <= now - self._zero:
            payload = self._incoming[self._next]["data"]
            self._next += 1
            count += 1
            if isinstance(payload, dict) and "unreadable" not in payload:
                self.received += 1
                for key, value in payload.items():
                    self.latest[key] = (now, value)
            else:
                self.unreadable += 1
        return count

    @property
    def exhausted(self) -> bool:
        return self._next >= len(self._incoming)

    def close(self) -> None:
        pass
