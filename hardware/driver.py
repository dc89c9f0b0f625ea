"""An RPLidar driver on pyserial: requests, motor, scanning, a reader thread, reconnects.

    lidar = RPLidar("/dev/rplidar", "a1", on_scan=lambda angles, ranges, stamp: print(len(ranges)))
    lidar.connect(); print(lidar.get_info(), lidar.get_health())
    lidar.start("typical")           # motor on, the scanner's typical mode, reader running
    ...
    lidar.close()                    # scan and motor stopped, port closed

The reader thread decodes bytes as they arrive (:mod:`swarmslam.hardware.stream`) into preallocated
rotation buffers (:class:`swarmslam.hardware.rotation.Rotations`) and calls ``on_scan(angles, ranges,
stamp)`` with each whole rotation — radians counter-clockwise in the robot frame, metres, and
the monotonic time the rotation ended. Nothing the scanner sends can raise in that thread:
damage is counted (``stats``). Silence longer than ``timeout`` restarts the scan; a port that
disappears (USB unplugged, the emulator's "vanish" fault) is reopened every ``retry`` seconds
until it is back, and scanning resumes.
"""

from __future__ import annotations

import threading
import time

import serial

from swarmslam.hardware import protocol as p
from swarmslam.hardware.models import ScanMode
from swarmslam.hardware.models import model as get_model
from swarmslam.hardware.rotation import Rotations
from swarmslam.hardware.stream import NodeStream, StreamStats, find_descriptor, stream_for

try:  # a port that vanishes mid-call fails in termios, which is not an OSError
    from termios import error as _termios_error

    PORT_ERRORS: tuple = (serial.SerialException, OSError, _termios_error)
except ImportError:  # no termios (Windows)
    PORT_ERRORS = (serial.SerialException, OSError)


class LidarError(OSError):
    """The scanner did not answer as the protocol says (names the request and what came)."""


class RPLidar:
    def __init__(self, port: str, model: str = "a1", timeout: float = 1.0, on_scan=None,
                 mount_yaw: float = 0.0, retry: float = 0.5, baud: int | None = None,
                 motor_speed: int | None = None):
        self.port = port
        self.model = get_model(model)
        self.baud = baud or self.model.baud
        self.timeout = timeout
        self.retry = retry
        self.motor_speed = motor_speed  # PWM (A2/A3, default 660) or rpm (S/C, default 600)
        self.stats = StreamStats()
        self.rotations = Rotations(on_scan, mount_yaw=mount_yaw)
        self.serial: serial.Serial | None = None
        self.mode = None  # the scan mode running (resolved), None when idle
        self.scan_mode = None  # the mode last started (resolved), kept across restarts
        self.motor_note = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()  # one request at a time on the port

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Open the port; :class:`LidarError` naming it if it cannot be opened or set up."""
        try:
            self.serial = serial.Serial(self.port, self.baud, timeout=0.05,
                                        write_timeout=self.timeout)
            self.serial.reset_input_buffer()
        except PORT_ERRORS as exc:
            if self.serial is not None:
                try:
                    self.serial.close()
                except PORT_ERRORS:
                    pass
                self.serial = None
            raise self._port_lost(exc) from None

    def close(self) -> None:
        """Stop scanning and the motor (best effort), then close the port."""
        self.stop()
        if self.serial is not None:
            try:
                self.stop_motor()
            except PORT_ERRORS:
                pass
            self.serial.close()
            self.serial = None

    def __enter__(self):
        self.connect()
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ requests (B1–B3)
    def send(self, command: int, payload: bytes = b"") -> None:
        try:
            self.serial.write(p.encode_request(command, payload))
            self.serial.flush()
        except PORT_ERRORS as exc:
            raise self._port_lost(exc) from None

    def _port_lost(self, exc) -> LidarError:
        """A port error as a :class:`LidarError` naming the port (termios's is no OSError)."""
        if isinstance(exc, LidarError):
            return exc
        detail = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        return LidarError(f"{self.port}: the port failed: {detail}")

    def request(self, command: int, payload: bytes = b"", answer: int | None = None,
                length: int | None = None) -> bytes:
        """Send a request and read its single response; :class:`LidarError` on silence or a
        wrong descriptor."""
        try:
            return self._request(command, payload, answer, length)
        except PORT_ERRORS as exc:
            raise self._port_lost(exc) from None

    def _request(self, command, payload, answer, length) -> bytes:
        name = f"request 0x{command:02X}"
        with self._lock:
            if self.mode is not None:
                raise LidarError(f"{name}: the scanner is scanning; call stop() first")
            self.serial.reset_input_buffer()
            self.send(command, payload)
            deadline = time.monotonic() + self.timeout
            descriptor, buffer = self._await_descriptor(name, deadline)
            if answer is not None and descriptor.answer_type != answer:
                raise LidarError(f"{name}: answer type 0x{descriptor.answer_type:02X}, "
                                 f"expected 0x{answer:02X}")
            if length is not None and descriptor.length != length:
                raise LidarError(f"{name}: {descriptor.length}-byte answer, expected {length}")
            while len(buffer) < descriptor.length:
                if time.monotonic() > deadline:
                    raise LidarError(f"{name}: answer cut short at {len(buffer)} of "
                                     f"{descriptor.length} bytes")
                buffer += self.serial.read(descriptor.length - len(buffer))
            return bytes(buffer[: descriptor.length])

    def _await_descriptor(self, name: str, deadline: float):
        """Read until a response descriptor arrives (bytes before it dropped and counted):
        ``(descriptor, the bytes after it)``, or :class:`LidarError` at ``deadline``."""
        buffer, received = bytearray(), 0
        while True:
            found = find_descriptor(buffer, self.stats)
            if found is not None:
                return found[0], buffer
            if time.monotonic() > deadline:
                raise LidarError(f"{name}: no response descriptor within {self.timeout} s "
                                 f"({received} other bytes received)")
            chunk = self.serial.read(max(1, self.serial.in_waiting))
            received += len(chunk)
            buffer += chunk

    def get_info(self) -> p.DeviceInfo:
        return p.decode_info(self.request(p.GET_INFO, answer=p.ANS_INFO, length=p.INFO_LEN))

    def get_health(self) -> tuple[int, int]:
        return p.decode_health(self.request(p.GET_HEALTH, answer=p.ANS_HEALTH, length=p.HEALTH_LEN))

    def get_samplerate(self) -> tuple[int, int]:
        return p.decode_samplerate(self.request(p.GET_SAMPLERATE, answer=p.ANS_SAMPLERATE,
                                                length=p.SAMPLERATE_LEN))

    def get_lidar_conf(self, conf_type: int, mode: int | None = None):
        reply = self.request(p.GET_LIDAR_CONF, p.lidar_conf_payload(conf_type, mode),
                             answer=p.ANS_LIDAR_CONF)
        decoded = p.decode_lidar_conf(reply)
        if decoded is None or decoded[0] != conf_type:
            raise LidarError(f"GET_LIDAR_CONF 0x{conf_type:X}: malformed reply {reply.hex(' ')}")
        return decoded[1]

    def negotiate_baud(self, bps: int, timeout: float = 1.5) -> int:
        """Switch the link to ``bps`` where the model allows (B7, the SDK's auto-baud): the
        port switches to the new rate, magic bytes go out until the scanner answers the rate
        it measured, and a confirmation makes it stay. Returns the measured rate. A scanner
        plugged in again starts at its default rate: a reconnect goes back to it."""
        allowed = (self.model.baud, *self.model.bauds)
        if bps not in allowed:
            raise ValueError(f"the {self.model.name.upper()} runs at "
                             f"{', '.join(str(b) for b in allowed)} bps, not {bps}")
        if self.mode is not None:
            raise LidarError("negotiate_baud: the scanner is scanning; call stop() first")
        with self._lock:
            try:
                self.serial.baudrate = bps
                self.serial.reset_input_buffer()
                deadline, reply = time.monotonic() + timeout, bytearray()
                while len(reply) < 4 and time.monotonic() < deadline:
                    self.serial.write(bytes((p.AUTOBAUD_MAGIC,)) * 16)
                    self.serial.flush()
                    reply += self.serial.read(4 - len(reply))
            except PORT_ERRORS as exc:
                raise self._port_lost(exc) from None
        if len(reply) < 4:
            raise LidarError(f"{self.port}: no answer to the baud negotiation at {bps} bps "
                             f"within {timeout} s (the scanner may not support it)")
        measured = int.from_bytes(reply[:4], "little")
        self.send(p.NEW_BAUDRATE_CONFIRM, p.baud_confirm_payload(bps))
        self.baud = bps
        return measured

    # ------------------------------------------------------------------ motor (B8)
    def start_motor(self) -> None:
        kind = self.model.motor
        if kind == "dtr":  # A1: clearing DTR spins the motor
            self._set_dtr(False)
        elif kind == "pwm":  # A2/A3: PWM if the accessory board says it takes it
            flag = self.request(p.GET_ACC_BOARD_FLAG, (0).to_bytes(4, "little"),
                                answer=p.ANS_ACC_BOARD_FLAG, length=4)
            if int.from_bytes(flag, "little") & 1:
                self.send(p.SET_MOTOR_PWM, p.motor_pwm_payload(self.motor_speed or p.DEFAULT_PWM))
            else:
                self._set_dtr(False)
        else:  # S-series, C1: speed in rpm
            self.send(p.HQ_MOTOR_SPEED_CTRL, p.motor_rpm_payload(self.motor_speed or 600))

    def stop_motor(self) -> None:
        kind = self.model.motor
        if kind == "dtr":
            self._set_dtr(True)
        elif kind == "pwm":
            self.send(p.SET_MOTOR_PWM, p.motor_pwm_payload(0))
            self._set_dtr(True)
        else:
            self.send(p.HQ_MOTOR_SPEED_CTRL, p.motor_rpm_payload(0))

    def _set_dtr(self, value: bool) -> None:
        try:
            self.serial.dtr = value
        except OSError as exc:  # a pseudo-terminal (the emulator) has no modem lines
            self.motor_note = f"DTR not settable on {self.port}: {exc.strerror}"

    # ------------------------------------------------------------------ scanning
    def scan_modes(self) -> list[ScanMode]:
        """The scan modes the scanner reports (GET_LIDAR_CONF, B3), by id."""
        count = self.get_lidar_conf(p.CONF_MODE_COUNT)
        return [ScanMode(k, self.get_lidar_conf(p.CONF_MODE_NAME, k),
                         self.get_lidar_conf(p.CONF_ANSWER_TYPE, k),
                         self.get_lidar_conf(p.CONF_US_PER_SAMPLE, k),
                         self.get_lidar_conf(p.CONF_MAX_DISTANCE, k)) for k in range(count)]

    def typical_mode(self) -> int:
        """The id of the mode Slamtec recommends for this scanner (what its SDK starts)."""
        return self.get_lidar_conf(p.CONF_TYPICAL_MODE)

    def resolve_mode(self, mode) -> ScanMode | str:
        """``mode`` as the scanner knows it: 'standard' and 'express' (legacy express, mode
        0 of EXPRESS_SCAN) as they are; 'typical', a mode name or an id from the scanner's own
        table. A scanner that answers no GET_LIDAR_CONF (firmware before 1.24) runs
        'typical' as 'express'."""
        if mode in ("standard", "express"):
            return mode
        try:
            modes = self.scan_modes()
            key = self.typical_mode() if mode == "typical" else mode
        except LidarError:
            if mode == "typical":
                return "express"
            raise
        for m in modes:
            if m.id == key or (isinstance(key, str) and m.name.lower() == key.lower()):
                return m
        raise ValueError(f"{self.port}: the scanner has no scan mode {mode!r} (it has "
                         f"{', '.join(m.name for m in modes)}, or standard, express, typical)")

    def start(self, mode="typical") -> None:
        """Motor on, scan started in ``mode`` (see :meth:`resolve_mode`), the reader thread
        running (it reopens the port first if the port vanished since it answered)."""
        if self._thread is not None:
            raise LidarError("already scanning")
        mode = self.resolve_mode(mode)
        self.scan_mode = mode
        try:
            self.start_motor()
            parser = self._start_scan(mode)
        except PORT_ERRORS:  # the port vanished since it answered: the reader reconnects
            parser = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._read_loop, args=(mode, parser),
                                        name="rplidar-reader", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the reader thread and the scan (the motor keeps turning)."""
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
        if self.mode is not None and self.serial is not None:
            try:
                self.send(p.STOP)
                time.sleep(0.1)  # the SDK waits 100 ms after STOP
                self.serial.reset_input_buffer()
            except PORT_ERRORS:
                pass
        self.mode = None

    def _start_scan(self, mode):
        """Send SCAN / EXPRESS_SCAN for a resolved mode, read the descriptor, return the
        stream parser."""
        self.mode = None
        name = mode if isinstance(mode, str) else f"{mode.name} (mode {mode.id})"
        with self._lock:
            self.serial.reset_input_buffer()
            if mode == "standard" or (not isinstance(mode, str)
                                      and mode.answer_type == p.ANS_NODE):
                self.send(p.SCAN)
            else:
                working_mode = 0 if mode == "express" else mode.id
                self.send(p.EXPRESS_SCAN, p.express_payload(working_mode))
            d, buffer = self._await_descriptor(f"{name} scan", time.monotonic() + self.timeout)
        self.rotations.reset()
        parser = stream_for(d.answer_type, self.rotations, self.stats)
        if parser is None:
            raise LidarError(f"{name} scan: answer type 0x{d.answer_type:02X} is not one we "
                             "decode (0x81 nodes; 0x82 express, 0x83 HQ, 0x84 ultra, 0x85 "
                             "dense, 0x86 ultra-dense capsules)")
        parser.feed(bytes(buffer))
        self.mode = mode
        return parser

    def _read_loop(self, mode: str, parser) -> None:
        if parser is None:
            parser = self._reconnect(mode)
        last_data = time.monotonic()
        while not self._stop.is_set():
            try:
                data = self.serial.read(max(1, self.serial.in_waiting))
            except (*PORT_ERRORS, TypeError, AttributeError):
                parser = self._reconnect(mode)  # the port vanished
                last_data = time.monotonic()
                continue
            now = time.monotonic()
            if data:
                parser.feed(data)
                last_data = now
            elif now - last_data > self.timeout:  # a stall: restart the scan
                self.stats.timeouts += 1
                try:
                    self.mode = None
                    self.send(p.STOP)
                    parser = self._start_scan(mode)
                except PORT_ERRORS:
                    pass
                last_data = time.monotonic()
        self.stats.rotations = self.rotations.rotations

    def _reconnect(self, mode: str):
        self.stats.reconnects += 1
        self.mode = None
        try:
            self.serial.close()
        except (*PORT_ERRORS, AttributeError):
            pass
        self.baud = self.model.baud  # re-plugged, the scanner starts at its default rate
        while not self._stop.is_set():
            try:
                self.connect()
                self.start_motor()
                return self._start_scan(mode)
            except PORT_ERRORS:
                self._stop.wait(self.retry)
        return NodeStream(self.rotations, self.stats)  # stopping: an idle parser

    def report(self) -> dict:
        out = self.stats.as_dict()
        out["rotations"] = self.rotations.rotations
        out["short_rotations"] = self.rotations.short
        out["overflow_samples"] = self.rotations.overflows
        if self.rotations.callback_errors:
            out["on_scan_errors"] = self.rotations.callback_errors
            out["last_on_scan_error"] = self.rotations.last_error
        if self.motor_note:
            out["motor_note"] = self.motor_note
        return out
