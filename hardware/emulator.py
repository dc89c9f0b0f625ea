"""A virtual RPLidar on a pseudo-terminal: the same bytes as the device, with faults on demand.

    emulator = VirtualRPLidar(source, model="a1", faults=Faults(garbage=0.01), link="/tmp/lidar")
    path = emulator.start()          # connect any RPLidar client to ``path``
    ...
    emulator.stop()

It answers GET_INFO, GET_HEALTH, GET_SAMPLERATE, GET_LIDAR_CONF, GET_ACC_BOARD_FLAG, motor
commands, STOP and RESET. SCAN streams standard nodes; EXPRESS_SCAN streams, for working mode 0,
the model's legacy express answer (express capsules on the A-series, dense on the S-series and
C1), and for a mode id the answer of that scan mode in the model's table
(:data:`swarmslam.hardware.models.MODELS`: express, ultra, dense, ultra-dense or HQ capsules) at its
sample rate; GET_LIDAR_CONF describes every mode and names the typical one. The ranges come
from a *source*: ``source.distances(angles_deg)`` gives distances in mm (0: no return) at the
scanner's clockwise angles for the rotation under way, and ``source.next_rotation()`` moves on
(:class:`swarmslam.emulator_sources.CarmenSource`, :class:`swarmslam.emulator_sources.WorldSource`).

Faults: garbage bytes between packets, corrupted packets (a capsule's checksum, a node's flag
bits), stalls (the stream stops for a while), and a vanishing port (the pseudo-terminal is
closed and a new one opened ``vanish_for`` seconds later; ``link`` — a symlink, as udev would
give — then points at the new one, so clients reconnect by name).
"""

from __future__ import annotations

import fcntl
import math
import os
import select
import struct
import threading
import time
import tty
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarmslam.hardware import protocol as p
from swarmslam.hardware.models import model as get_model

TCGETS2 = 0x802C542A  # Linux: read a terminal's termios2 (its speeds as numbers)
STANDARD_US = 508  # µs per sample in standard mode (A-series)
BOOT_TEXT = b"RP LIDAR System.\r\nFirmware Ver 1.29 - rtm, HW Ver 7\r\nModel: 18\r\n"


@dataclass(frozen=True)
class Faults:
    garbage: float = 0.0  # probability per packet of 1–24 random bytes before it
    corrupt: float = 0.0  # probability per packet of one flipped byte (checksum / flag bits)
    stall_every: float = 0.0  # s between stalls (0: none)
    stall_for: float = 0.0  # s each stall lasts
    vanish_after: float = 0.0  # s of streaming before the port vanishes (0: never)
    vanish_for: float = 0.5  # s until it comes back

    def __post_init__(self):
        for name in ("garbage", "corrupt"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:  # NaN fails too
                raise ValueError(f"{name} is a probability in [0, 1], got {v}")
        for name in ("stall_every", "stall_for", "vanish_after", "vanish_for"):
            v = getattr(self, name)
            if not (v >= 0.0 and math.isfinite(v)):
                raise ValueError(f"{name} is seconds ≥ 0, got {v}")

    @classmethod
    def parse(cls, text: str) -> Faults:
        """``garbage=0.01,corrupt=0.01,stall=10:2,vanish=30:1`` (stall/vanish: every:for)."""
        values = {}
        for item in filter(None, (t.strip() for t in text.split(","))):
            key, _, value = item.partition("=")
            try:
                if key in ("garbage", "corrupt"):
                    values[key] = float(value)
                elif key in ("stall", "vanish"):
                    every, _, length = value.partition(":")
                    values["stall_every" if key == "stall" else "vanish_after"] = float(every)
                    values["stall_for" if key == "stall" else "vanish_for"] = float(length or 1.0)
                else:
                    raise ValueError(f"unknown fault {key!r}")
            except ValueError as exc:
                raise ValueError(f"--faults {item!r}: {exc} (use e.g. garbage=0.01,corrupt=0.01,"
                                 "stall=10:2,vanish=30:1)") from None
        try:
            return cls(**values)
        except ValueError as exc:
            raise ValueError(f"--faults {text!r}: {exc}") from None


PTY_FOLDER = "/dev/pts/"  # where a link of an earlier emulator (one killed) points


def refuse_to_replace(link: Path) -> None:
    """Raise FileExistsError unless ``link`` is free, or a link an emulator made (to a
    pseudo-terminal): a file, a folder or a link to anything else is the user's."""
    if not (link.exists() or link.is_symlink()):
        return
    if link.is_symlink() and os.readlink(link).startswith(PTY_FOLDER):
        return
    kind = "a symbolic link to " + os.readlink(link) if link.is_symlink() else \
        "a folder" if link.is_dir() else "a file"
    raise FileExistsError(f"--link {link}: is {kind}, which the emulator will not replace; "
                          f"name a free path")


class VirtualRPLidar:
    def __init__(self, source, model: str = "a1", faults: Faults | None = None, seed: int = 0,
                 link: str | os.PathLike | None = None, typical: str | None = None):
        """``typical``: the scan mode (a name in the model's table) advertised as typical
        instead of the model's own, to try a client on each mode."""
        self.source = source
        self.model = get_model(model)
        self.typical = self.model.mode(typical).id if typical else self.model.typical
        self.baud = self.model.baud  # the rate negotiated last (B7)
        self.faults = faults or Faults()
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.link = Path(link) if link else None
        self.info = p.DeviceInfo((self.model.major_id << 4) | 0x08, 29, 1, 7,
                                 bytes(range(0x10, 0x20)))
        self.master = -1
        self.slave = -1
        self.path = ""
        self.scanning: int | None = None  # the answer type streaming, None when idle
        self.motor_on = self.model.motor == "dtr"  # a pty has no DTR line: A1 always spins
        self.stats = {"requests": 0, "packets": 0, "rotations": 0, "garbage_bytes": 0,
                      "corrupted": 0, "stalls": 0, "vanished": 0, "overflow_bytes": 0,
                      "unknown_requests": 0}
        self.sent = bytearray()  # every byte written, when record=True (tests)
        self.record = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rx = bytearray()
        self._tx = bytearray()
        self._one = np.zeros(1)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> str:
        if self.link is not None:
            refuse_to_replace(self.link)
        self._open_pty()
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="rplidar-emulator", daemon=True)
        self._thread.start()
        return str(self.link) if self.link else self.path

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self._close_pty()
        if self.link is not None and self.link.is_symlink():
            self.link.unlink()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()

    def _open_pty(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".new")
            tmp.unlink(missing_ok=True)
            os.symlink(self.path, tmp)
            os.replace(tmp, self.link)

    def _close_pty(self) -> None:
        for fd in (self.master, self.slave):
            if fd >= 0:
                os.close(fd)
        self.master = self.slave = -1

    # ------------------------------------------------------------------ the device
    def _serve(self) -> None:
        started = time.monotonic()
        next_stall = started + self.faults.stall_every if self.faults.stall_every else math.inf
        vanish_at = started + self.faults.vanish_after if self.faults.vanish_after else math.inf
        stream_clock = None  # when the bytes streamed so far are due
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.002)
            if ready:
                try:
                    self._rx += os.read(self.master, 4096)
                except OSError:
                    pass
                self._handle_requests()
            now = time.monotonic()
            if now >= vanish_at:
                self._vanish()
                vanish_at = math.inf
                continue
            if self.scanning and self.motor_on:
                if now >= next_stall:
                    self.stats["stalls"] += 1
                    self._stop.wait(self.faults.stall_for)
                    next_stall = time.monotonic() + self.faults.stall_every
                    stream_clock = None
                    continue
                if stream_clock is None:
                    stream_clock = now
                # keep the stream at the device's pace: packets until the clock catches up
                while stream_clock <= now and len(self._tx) < 8192:
                    packet, seconds = self._next_packet()
                    self._queue(packet)
                    stream_clock += seconds
            else:
                stream_clock = None
            self._flush()

    def _vanish(self) -> None:
        self.stats["vanished"] += 1
        self._close_pty()
        if self.link is not None and self.link.is_symlink():
            self.link.unlink()
        self._rx.clear()
        self._tx.clear()
        self._stop.wait(self.faults.vanish_for)
        if not self._stop.is_set():
            self._open_pty()  # a new device node, as after a USB re-plug
        self.scanning = None  # powered up again: idle until asked

    def _queue(self, packet: bytes) -> None:
        f = self.faults
        if f.garbage and self.rng.random() < f.garbage:
            junk = self.rng.integers(0, 256, int(self.rng.integers(1, 25)), dtype=np.uint8).tobytes()
            self._tx += junk
            self.stats["garbage_bytes"] += len(junk)
        if f.corrupt and self.rng.random() < f.corrupt:
            packet = bytearray(packet)
            if len(packet) == p.NODE_LEN:
                packet[0] |= 0b11  # S == ¬S: no longer a node
            else:
                packet[int(self.rng.integers(4, len(packet)))] ^= 1 << int(self.rng.integers(8))
            packet = bytes(packet)
            self.stats["corrupted"] += 1
        self._tx += packet
        self.stats["packets"] += 1

    def _flush(self) -> None:
        if not self._tx or self.master < 0:
            return
        try:
            n = os.write(self.master, self._tx)
        except BlockingIOError:
            n = 0
        except OSError:
            self._tx.clear()
            return
        if self.record:
            self.sent += self._tx[:n]
        del self._tx[:n]
        if len(self._tx) > 65536:  # nobody reads: a UART would overrun
            self.stats["overflow_bytes"] += len(self._tx)
            self._tx.clear()

    def _reply(self, answer_type: int, payload: bytes, mode: int = p.SINGLE) -> None:
        self._tx += p.encode_descriptor(len(payload), mode, answer_type) + payload

    def _handle_requests(self) -> None:
        if self._rx.startswith(bytes((p.AUTOBAUD_MAGIC,)) * 4) and self.model.bauds:
            # a host negotiating a new rate: answer the rate the link runs at now
            self._tx += struct.pack("<I", self._link_bps())
            self._rx.clear()
            return
        while self._rx:
            parsed = p.decode_request(self._rx)
            if parsed is None:
                return
            command, payload, used = parsed
            del self._rx[:used]
            if command is None:
                continue
            self.stats["requests"] += 1
            self._answer(command, payload)

    def _answer(self, command: int, payload: bytes) -> None:
        m = self.model
        if command == p.GET_INFO:
            self._reply(p.ANS_INFO, p.encode_info(self.info))
        elif command == p.GET_HEALTH:
            self._reply(p.ANS_HEALTH, p.encode_health(0, 0))
        elif command == p.GET_SAMPLERATE:
            self._reply(p.ANS_SAMPLERATE, p.encode_samplerate(STANDARD_US, self._express_us()))
        elif command == p.GET_LIDAR_CONF:
            self._answer_conf(payload)
        elif command == p.GET_ACC_BOARD_FLAG:
            flag = 1 if m.motor == "pwm" else 0
            self._reply(p.ANS_ACC_BOARD_FLAG, flag.to_bytes(4, "little"))
        elif command in (p.SET_MOTOR_PWM, p.HQ_MOTOR_SPEED_CTRL):
            if m.motor != "dtr" and len(payload) == 2:
                self.motor_on = int.from_bytes(payload, "little") > 0
        elif command in (p.SCAN, p.FORCE_SCAN):
            self._start_stream(p.ANS_NODE, STANDARD_US)
        elif command == p.EXPRESS_SCAN:
            working_mode = payload[0] if payload else 0
            if working_mode == 0 or not m.modes:  # legacy express: the model's capsules
                self._start_stream(m.express_answer, self._express_us())
            elif working_mode < len(m.modes):
                mode = m.modes[working_mode]
                self._start_stream(mode.answer_type, mode.us_per_sample)
            else:
                self.stats["unknown_requests"] += 1  # no such mode: a real device stays idle
        elif command == p.NEW_BAUDRATE_CONFIRM:
            bps = p.decode_baud_confirm(payload)
            if bps in (m.baud, *m.bauds):
                self.baud = bps  # a pseudo-terminal carries any rate: only the record
            else:
                self.stats["unknown_requests"] += 1
        elif command == p.STOP:
            self.scanning = None
        elif command == p.RESET:
            self.scanning = None
            self.motor_on = m.motor == "dtr"
            self._tx += BOOT_TEXT
        else:
            self.stats["unknown_requests"] += 1  # a real device ignores what it does not know

    def _answer_conf(self, payload: bytes) -> None:
        if len(payload) < 4:
            return
        conf_type = int.from_bytes(payload[:4], "little")
        modes = self.model.modes
        k = int.from_bytes(payload[4:6], "little") if len(payload) >= 6 else 0
        mode = modes[min(k, len(modes) - 1)]
        values = {
            p.CONF_MODE_COUNT: len(modes),
            p.CONF_US_PER_SAMPLE: mode.us_per_sample,
            p.CONF_MAX_DISTANCE: mode.max_distance,
            p.CONF_ANSWER_TYPE: mode.answer_type,
            p.CONF_TYPICAL_MODE: self.typical,
            p.CONF_MODE_NAME: mode.name,
        }
        if conf_type in values:
            self._reply(p.ANS_LIDAR_CONF, p.encode_lidar_conf(conf_type, values[conf_type]))

    def _link_bps(self) -> int:
        """The rate the host set on its end of the pseudo-terminal (termios2's speed)."""
        try:
            raw = fcntl.ioctl(self.master, TCGETS2, bytes(44))
            return struct.unpack_from("<I", raw, 36)[0]
        except OSError:
            return self.baud

    def _express_us(self) -> int:
        return round(1e6 / self.model.samples_per_second)

    # ------------------------------------------------------------------ the stream
    PACKETS = {  # answer type: (descriptor length, samples per packet)
        p.ANS_NODE: (p.NODE_LEN, 1), p.ANS_CAPSULE: (p.CAPSULE_LEN, 32),
        p.ANS_DENSE: (p.CAPSULE_LEN, 40), p.ANS_ULTRA: (p.ULTRA_LEN, 96),
        p.ANS_ULTRA_DENSE: (p.ULTRA_DENSE_LEN, 64), p.ANS_HQ: (p.HQ_LEN, p.HQ_NODES)}

    def _start_stream(self, answer_type: int, us_per_sample: float) -> None:
        """Answer a scan request with its descriptor, and stream ``answer_type`` packets at
        one sample per ``us_per_sample``."""
        length, per_packet = self.PACKETS[answer_type]
        self._tx += p.encode_descriptor(length, p.MULTIPLE, answer_type)
        self.scanning = answer_type
        self._per_packet = per_packet
        self._first_capsule = True
        self._ultra_first = None  # an ultra capsule's first sample, measured ahead (mm)
        rate = 1e6 / us_per_sample
        self._per_rotation = max(int(round(rate / self.model.scan_hz)), 32)
        self._sample_seconds = 1.0 / rate
        self._angle_q16 = int(self.rng.integers(0, p.FULL_CIRCLE_Q16))  # where the head is
        self.source.reset()

    def _next_packet(self) -> tuple[bytes, float]:
        """The next packet of the stream and how long the device takes to measure it."""
        kind = self.scanning
        seconds = self._per_packet * self._sample_seconds
        if kind == p.ANS_NODE:
            return self._next_node(), seconds
        if kind == p.ANS_HQ:
            return self._next_hq(), seconds
        if kind == p.ANS_ULTRA:
            return self._next_ultra(), seconds
        return self._next_capsule(kind), seconds

    def _step_q16(self) -> int:
        return p.FULL_CIRCLE_Q16 // self._per_rotation

    def _next_node(self) -> bytes:
        step = self._step_q16()
        start = self._angle_q16 < step  # the first sample past 0°
        if start:
            self._new_rotation()
        jitter = int(self.rng.integers(-step // 8, step // 8 + 1))
        angle_q6 = ((self._angle_q16 + jitter) % p.FULL_CIRCLE_Q16) >> 10
        self._one[0] = angle_q6 / 64.0
        dist_mm = float(self.source.distances(self._one)[0])
        dist_q2 = min(int(round(dist_mm * 4)), 0xFFFF)
        quality = 47 if dist_q2 else 0
        self._angle_q16 = (self._angle_q16 + step) % p.FULL_CIRCLE_Q16
        return p.encode_node(quality, angle_q6, dist_q2, start)

    def _measure(self, angles_deg, starts) -> np.ndarray:
        """Distances (mm) at these angles, the rotation switching where a sample starts one."""
        wrap = next((k for k, start in enumerate(starts) if start), len(starts))
        mm = np.zeros(len(starts))
        if wrap:
            mm[:wrap] = self.source.distances(np.asarray(angles_deg[:wrap]))
        if wrap < len(starts):
            self._new_rotation()
            mm[wrap:] = self.source.distances(np.asarray(angles_deg[wrap:]))
        return mm

    def _advance(self, n: int) -> tuple[int, int, bool]:
        """This packet's start angle (Q6), the next one's, and whether it is the first."""
        step = self._step_q16()
        start_q6 = self._angle_q16 >> 10
        next_q6 = ((self._angle_q16 + n * step) % p.FULL_CIRCLE_Q16) >> 10
        first, self._first_capsule = self._first_capsule, False
        self._angle_q16 = (self._angle_q16 + n * step) % p.FULL_CIRCLE_Q16
        return start_q6, next_q6, first

    def _next_capsule(self, kind: int) -> bytes:
        """An express, dense or ultra-dense capsule starting at the head's angle; its samples'
        angles are decoded the SDK's way from this capsule's start and the next one's, so the
        distances are measured where every client will place them."""
        n = self._per_packet
        start_q6, next_q6, first = self._advance(n)
        express = kind == p.ANS_CAPSULE
        offsets = tuple(int(v) for v in self.rng.integers(0, 16, n)) if express else ()
        if kind == p.ANS_ULTRA_DENSE:
            probe = p.Capsule(start_q6, False, (0,) * n, ())
            samples = p.ultra_dense_capsule_samples(probe, next_q6, [0, False])
        else:
            samples = p.capsule_samples(p.Capsule(start_q6, False, (0,) * n, offsets), next_q6)
        mm = self._measure([s[2] / 64.0 for s in samples], [s[0] for s in samples])
        if kind == p.ANS_ULTRA_DENSE:
            return p.encode_ultra_dense_capsule(start_q6, first, mm, time_stamp=self._stamp_us())
        limit = 0xFFFF if kind == p.ANS_DENSE else 0x3FFF
        distances = [min(int(round(d)), limit) for d in mm]
        if kind == p.ANS_DENSE:
            return p.encode_dense_capsule(start_q6, first, distances)
        return p.encode_express_capsule(start_q6, first, distances, offsets)

    def _next_ultra(self) -> bytes:
        """An ultra capsule: each sample measured where the SDK's optical model will put it
        (its offset depends on the distance: measured at the mean offset, then once more at
        the offset of that distance), the next capsule's first sample measured ahead."""
        start_q6, next_q6, first = self._advance(96)
        probe = p.Capsule(start_q6, False, (0,) * 32, ())
        after = p.Capsule(next_q6, False, (0,) * 32, ())
        nominal = p.ultra_capsule_samples(probe, after)  # at no distance: the mean offset
        mean = p._ultra_offset_q16(0) / 65536.0
        angles = np.array([s[2] / 64.0 + mean for s in nominal])  # the head's angles
        starts = [s[0] for s in nominal]
        mm = self._measure(angles - mean, starts)
        refined = np.array([p._ultra_offset_q16(int(d) * 4) / 65536.0 for d in mm])
        mm = self.source.distances(angles - refined)
        if self._ultra_first is not None:
            mm[0] = self._ultra_first
        self._one[0] = (next_q6 / 64.0) - mean
        self._ultra_first = float(self.source.distances(self._one)[0])
        distances = [int(round(d)) for d in mm]
        return p.encode_ultra_capsule(start_q6, first, distances, int(round(self._ultra_first)))

    def _next_hq(self) -> bytes:
        """An HQ capsule: 96 nodes with their own angles (Q14) and rotation flags."""
        step = self._step_q16()
        nodes = []
        for _ in range(p.HQ_NODES):
            start = self._angle_q16 < step
            if start:
                self._new_rotation()
            z = (self._angle_q16 * 16384) // (90 << 16)  # Q14 of 90°
            self._one[0] = z * 90.0 / 16384.0
            dist_q2 = min(int(round(float(self.source.distances(self._one)[0]) * 4)), 2**32 - 1)
            nodes.append((z, dist_q2, 188 if dist_q2 else 0, start))
            self._angle_q16 = (self._angle_q16 + step) % p.FULL_CIRCLE_Q16
        return p.encode_hq_capsule(nodes, self._stamp_us())

    def _stamp_us(self) -> int:
        return int(time.monotonic() * 1e6)

    def _new_rotation(self) -> None:
        self.stats["rotations"] += 1
        self.source.next_rotation()
