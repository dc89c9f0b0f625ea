"""Stream parsers: bytes as they arrive → samples, resynchronising after damage (B9).

Nothing here raises on bad data. A damaged stream costs the samples it damaged, counted in
:class:`StreamStats`; every good packet after it is decoded. Parsers hand each sample to a
sink's ``add(start, quality, angle_q6, distance_q2)`` (:class:`swarmslam.hardware.rotation.Rotations`).

* Responses: :func:`find_descriptor` skips to the next ``A5 5A`` as the SDK's header state
  machine does.
* Standard nodes (no checksum): slide byte by byte until the flag bits are right (S ≠ ¬S,
  C = 1) *and* the angle follows the previous one (a step back of more than 2°, or forward of
  more than 30°, without the new-rotation flag is a misaligned read; a new-rotation node must
  lie within 30° past 0°, after an angle in the previous half turn). After damage the parser
  looks 16 bytes ahead and resumes at the first node that lies within 5° of the last good one
  (unless an overlapping one is also followed by a node), else at the first node followed by
  a node; after 10 bytes without a node the angle check restarts, so a false node cannot lock
  the parser out.
* Capsules (express 0x82, dense 0x85, ultra 0x84, ultra-dense 0x86; :data:`FORMATS`): slide
  until the sync nibbles match; a checksum mismatch
  drops the capsule and its cached predecessor (the SDK's rule). The mismatch counts as a
  checksum error once the parser has passed its 84 bytes without finding a good capsule inside
  them — otherwise it was a false sync inside garbage (a resync), and nothing is dropped — so
  garbage never costs the capsules around it. After damage a capsule is taken only if its
  start angle lies a whole number of capsule steps (±¼) past the last good one and a good
  capsule follows it, within 32 bytes of garbage, one step on (sync nibbles and the 8-bit sum
  pass by chance once in 65,536 positions slid over; these checks make a false capsule
  thousands of times rarer still).
  The angle chain survives garbage between two good capsules; a start angle jumping more
  than ``max_capsule_step`` from its predecessor (a lost capsule) restarts it.
* HQ capsules (0x83): slide until a sync byte starts 781 bytes whose CRC-32 holds; their nodes
  carry their own angles and rotation flags.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

from swarmslam.hardware.protocol import (
    ANS_CAPSULE,
    ANS_DENSE,
    ANS_HQ,
    ANS_NODE,
    ANS_ULTRA,
    ANS_ULTRA_DENSE,
    CAPSULE_LEN,
    DESCRIPTOR_LEN,
    FULL_CIRCLE_Q6,
    HQ_LEN,
    NODE_LEN,
    SYNC,
    SYNC2,
    ULTRA_DENSE_LEN,
    ULTRA_LEN,
    capsule_samples,
    check_capsule,
    decode_capsule,
    decode_descriptor,
    decode_hq_capsule,
    decode_node,
    decode_ultra_capsule,
    decode_ultra_dense_capsule,
    ultra_capsule_samples,
    ultra_dense_capsule_samples,
)


class CapsuleFormat(NamedTuple):
    """What differs between the capsule answers: size, where the start angle sits, how a
    capsule is read, and how its samples come out once the next capsule is in."""

    length: int
    angle_at: int
    decode: Callable  # (buffer, offset) -> Capsule
    samples: Callable  # (previous, current, state) -> [(start, quality, angle_q6, dist_q2)]


FORMATS = {
    ANS_CAPSULE: CapsuleFormat(CAPSULE_LEN, 2, lambda b, i: decode_capsule(b, i, False),
                               lambda prev, cur, state: capsule_samples(prev, cur.start_angle_q6)),
    ANS_DENSE: CapsuleFormat(CAPSULE_LEN, 2, lambda b, i: decode_capsule(b, i, True),
                             lambda prev, cur, state: capsule_samples(prev, cur.start_angle_q6)),
    ANS_ULTRA: CapsuleFormat(ULTRA_LEN, 2, decode_ultra_capsule,
                             lambda prev, cur, state: ultra_capsule_samples(prev, cur)),
    ANS_ULTRA_DENSE: CapsuleFormat(
        ULTRA_DENSE_LEN, 8, decode_ultra_dense_capsule,
        lambda prev, cur, state: ultra_dense_capsule_samples(prev, cur.start_angle_q6, state)),
}


class StreamStats:
    FIELDS = ("bytes", "samples", "rotations", "checksum_errors", "resyncs", "dropped_bytes",
              "timeouts", "reconnects")

    def __init__(self):
        for name in self.FIELDS:
            setattr(self, name, 0)

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name in self.FIELDS}


def find_descriptor(buffer: bytearray, stats: StreamStats | None = None):
    """The first response descriptor in ``buffer``: ``(descriptor, bytes consumed)``; bytes
    before it are dropped (counted). ``None`` if no complete descriptor is there yet (the
    buffer keeps a trailing ``A5`` that may start one)."""
    i = 0
    while True:
        j = buffer.find(bytes((SYNC, SYNC2)), i)
        if j < 0:
            keep = 1 if buffer[-1:] == bytes((SYNC,)) else 0
            _drop(buffer, len(buffer) - keep, stats)
            return None
        if len(buffer) - j < DESCRIPTOR_LEN:
            _drop(buffer, j, stats)
            return None
        descriptor = decode_descriptor(buffer[j : j + DESCRIPTOR_LEN])
        _drop(buffer, j, stats)
        del buffer[:DESCRIPTOR_LEN]
        return descriptor, j + DESCRIPTOR_LEN


def _drop(buffer: bytearray, n: int, stats) -> None:
    if n > 0:
        del buffer[:n]
        if stats is not None:
            stats.dropped_bytes += n
            stats.resyncs += 1


class _Parser:
    def __init__(self, sink, stats: StreamStats | None):
        self.sink = sink
        self.stats = stats or StreamStats()
        self.buffer = bytearray()
        self.resyncing = False

    def _append(self, data) -> tuple[bytearray, int]:
        self.buffer += data
        self.stats.bytes += len(data)
        return self.buffer, len(self.buffer)


class NodeStream(_Parser):
    """Standard-scan nodes (answer type 0x81)."""

    BACK_Q6 = 2 * 64
    FORWARD_Q6 = 30 * 64
    NEAR_Q6 = 5 * 64
    WINDOW = 16  # bytes looked ahead when resynchronising

    def __init__(self, sink, stats: StreamStats | None = None):
        super().__init__(sink, stats)
        self.last_angle = -1  # unknown
        self.missed = 0  # bytes skipped since the last good node

    def feed(self, data) -> None:
        buf, n = self._append(data)
        stats, i = self.stats, 0
        while n - i >= 2 * NODE_LEN:  # a node is judged with its successor in view
            node = decode_node(buf, i)
            # a node near the last one is taken; after damage it must also be followed by one
            if not (self._close(node, self.last_angle)
                    and (not self.resyncing or self._ahead(buf, i, node))):
                if n - i < self.WINDOW + 2 * NODE_LEN:
                    break  # damage suspected: decide with enough bytes in view
                j = self._resync_offset(buf, i)
                if j != i:
                    self._skip(j - i if j >= 0 else 1)
                    i = j if j >= 0 else i + 1
                    continue
            start, quality, angle_q6, distance_q2 = node
            self.last_angle = angle_q6
            self.missed = 0
            self.resyncing = False
            stats.samples += 1
            self.sink.add(start, quality, angle_q6, distance_q2)
            i += NODE_LEN
        del buf[:i]

    def _follows(self, node, last_angle: int) -> bool:
        if node is None:
            return False
        start, _, angle, _ = node
        if angle >= FULL_CIRCLE_Q6:
            return False
        if start:  # the first sample past 0°, after the last one of the turn before
            return angle < self.FORWARD_Q6 and (last_angle < 0 or last_angle - angle > FULL_CIRCLE_Q6 // 2)
        if last_angle < 0:
            return True
        step = angle - last_angle
        return -self.BACK_Q6 <= step <= self.FORWARD_Q6

    def _close(self, node, last_angle: int) -> bool:
        """Follows ``last_angle`` within a few samples (a new rotation's node: as it should)."""
        if not self._follows(node, last_angle):
            return False
        if last_angle < 0:
            return True
        if node[0]:
            return node[2] <= self.NEAR_Q6 and last_angle >= FULL_CIRCLE_Q6 - self.NEAR_Q6
        return 0 <= node[2] - last_angle <= self.NEAR_Q6

    def _ahead(self, buf, i: int, node) -> bool:
        return self._follows(decode_node(buf, i + NODE_LEN), node[2])

    def _resync_offset(self, buf, i: int) -> int:
        """Where the stream resumes, looking up to WINDOW bytes ahead: the first node near
        the last good one — unless a node overlapping it is near *and* followed by a node
        (then that one: both cannot be real) — else the first node followed by a node; -1 if
        none."""
        first_close = first_ahead = -1
        for j in range(i, i + self.WINDOW):
            if first_close >= 0 and j >= first_close + NODE_LEN:
                break
            node = decode_node(buf, j)
            if not self._follows(node, self.last_angle):
                continue
            ahead = self._ahead(buf, j, node)
            if self._close(node, self.last_angle):
                if ahead:
                    return j
                if first_close < 0:
                    first_close = j
            elif ahead and first_ahead < 0:
                first_ahead = j
        return first_close if first_close >= 0 else first_ahead

    def _skip(self, count: int) -> None:
        self.stats.dropped_bytes += count
        if not self.resyncing:
            self.resyncing = True
            self.stats.resyncs += 1
        self.missed += count
        if self.missed > 2 * NODE_LEN:
            self.last_angle = -1


class CapsuleStream(_Parser):
    """Express (0x82, 32 samples), dense (0x85, 40), ultra (0x84, 96) or ultra-dense (0x86,
    64) capsules: ``answer_type`` (or ``dense`` for 0x85 over 0x82)."""

    GAP = 32  # bytes of garbage tolerated between a capsule and the one confirming it

    def __init__(self, sink, dense: bool = False, stats: StreamStats | None = None,
                 max_capsule_step_deg: float = 90.0, answer_type: int | None = None):
        super().__init__(sink, stats)
        self.answer_type = answer_type or (ANS_DENSE if dense else ANS_CAPSULE)
        self.format = FORMATS[self.answer_type]
        self.length = self.format.length
        self.state = [0, False]  # what a format carries from sample to sample (ultra-dense)
        self.previous = None  # the capsule waiting for its successor's start angle
        self.max_step_q6 = int(max_capsule_step_deg * 64)
        self.suspect_end = 0  # bytes left of a capsule whose checksum failed (0: none)
        self.last_start = -1  # start angle of the last good capsule
        self.step_q6 = 0  # start-angle step between consecutive capsules (0: not seen yet)
        self.skipped = 0  # bytes slid over since the last good capsule

    def feed(self, data) -> None:
        buf, n = self._append(data)
        stats, i = self.stats, 0
        while n - i >= self.length:
            status = check_capsule(buf, i, self.length)
            if status == 0 and (self.suspect_end > 0 or self.resyncing):
                # after damage a capsule counts only if its angle continues the chain and a
                # good capsule follows it (up to GAP bytes of garbage later), one step on:
                # sync nibbles and an 8-bit sum pass by chance once in 65,536 positions
                if n - i < 2 * self.length + self.GAP:
                    break
                if not self._confirmed(buf, i):
                    status = 1
            if status == 0:
                if self.suspect_end > 0:  # a good capsule inside the suspect: a false sync
                    self.suspect_end = 0
                    stats.resyncs += 1
                capsule = self.format.decode(buf, i)
                self._chain(capsule)
                self.resyncing = False
                i += self.length
                continue
            if status == 2 and self.suspect_end <= 0:
                self.suspect_end = self.length
            self._skip()
            i += 1
        del buf[:i]

    def _skip(self) -> None:
        self.stats.dropped_bytes += 1
        self.skipped += 1
        if self.suspect_end > 0:
            self.suspect_end -= 1
            if self.suspect_end == 0:  # a capsule's length with no good one: corrupt
                self.stats.checksum_errors += 1
                self.previous = None  # its successor's angles cannot be trusted across it
            self.resyncing = True
            return
        if not self.resyncing:
            self.resyncing = True
            self.stats.resyncs += 1

    def _start_q6(self, buf, i: int) -> int:
        k = i + self.format.angle_at
        return (buf[k] | (buf[k + 1] << 8)) & 0x7FFF

    def _confirmed(self, buf, i: int) -> bool:
        start = self._start_q6(buf, i)
        if self.last_start >= 0 and self.skipped <= 4 * self.length:  # else: start afresh
            lost = 2 + self.skipped // self.length  # capsules the damage may have taken
            if not self._steps(start - self.last_start, lost):
                return False
        for j in range(i + self.length, i + self.length + self.GAP + 1):
            if (check_capsule(buf, j, self.length) == 0
                    and self._steps(self._start_q6(buf, j) - start, 1)):
                return True
        return False

    def _steps(self, delta_q6: int, most: int) -> bool:
        """Is ``delta`` 1..``most`` capsule steps (±¼ step), or, before a step was seen, a
        forward move within ``max_capsule_step``?"""
        delta = delta_q6 % FULL_CIRCLE_Q6
        if self.step_q6 <= 0:
            return 0 < delta <= self.max_step_q6 * most
        for m in range(1, most + 1):
            if abs(delta - m * self.step_q6) <= self.step_q6 // 4:
                return True
        return False

    def _chain(self, capsule) -> None:
        previous = self.previous
        self.previous = capsule
        if previous is not None and self.skipped == 0:
            self.step_q6 = (capsule.start_angle_q6 - previous.start_angle_q6) % FULL_CIRCLE_Q6
        self.last_start = capsule.start_angle_q6
        self.skipped = 0
        if capsule.start or previous is None:
            return  # a new chain: this capsule's samples wait for the next one
        step = (capsule.start_angle_q6 - previous.start_angle_q6) % FULL_CIRCLE_Q6
        if step > self.max_step_q6:
            self.stats.resyncs += 1  # out of order: the chain restarts here
            return
        for start, quality, angle_q6, distance_q2 in self.format.samples(previous, capsule,
                                                                         self.state):
            self.stats.samples += 1
            self.sink.add(start, quality, angle_q6, distance_q2)


class HqStream(_Parser):
    """HQ capsules (0x83): 96 nodes each, checked by CRC-32; a failed check slides one byte
    (counted as a checksum error once a capsule's length passed without a good one)."""

    def __init__(self, sink, stats: StreamStats | None = None):
        super().__init__(sink, stats)
        self.suspect_end = 0

    def feed(self, data) -> None:
        buf, n = self._append(data)
        stats, i = self.stats, 0
        while n - i >= HQ_LEN:
            nodes = decode_hq_capsule(buf, i) if buf[i] == SYNC else None
            if nodes is not None:
                if self.suspect_end > 0:
                    self.suspect_end = 0
                    stats.resyncs += 1
                for start, quality, angle_q6, distance_q2 in nodes:
                    stats.samples += 1
                    self.sink.add(start, quality, angle_q6, distance_q2)
                self.resyncing = False
                i += HQ_LEN
                continue
            if buf[i] == SYNC and self.suspect_end <= 0:
                self.suspect_end = HQ_LEN
            stats.dropped_bytes += 1
            if self.suspect_end > 0:
                self.suspect_end -= 1
                if self.suspect_end == 0:
                    stats.checksum_errors += 1
            elif not self.resyncing:
                self.resyncing = True
                stats.resyncs += 1
            i += 1
        del buf[:i]


def stream_for(answer_type: int, sink, stats: StreamStats | None = None):
    """The parser for a scan answer type, or None if we do not decode it."""
    if answer_type == ANS_NODE:
        return NodeStream(sink, stats)
    if answer_type == ANS_HQ:
        return HqStream(sink, stats)
    if answer_type in FORMATS:
        return CapsuleStream(sink, stats=stats, answer_type=answer_type)
    return None
