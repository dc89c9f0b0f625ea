"""An RPLidar driver on pyserial: requests, motor, scanning, a reader thread, reconnects.

    lidar = RPLidar("/dev/rplidar", "a1", on_scan=lambda angles, ranges, stamp: print(len(ranges)))
    lidar.connect(); print(lidar.get_info(), lidar.get_health())
    lidar.start("express")           # motor on, scan started, reader thread running
    ...
    lidar.close()                    # scan and motor stopped, port closed

The reader thread decodes bytes as they arrive (:mod:`hardware.stream`) into preallocated
rotation buffers (:class:`hardware.rotation.Rotations`) and calls ``on_scan(angles, ranges,
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

from hardware import protocol as p
from hardware.models import model as get_model
from hardware.rotation import Rotations
from hardware.stream import CapsuleStream, NodeStream, StreamStats, find_descriptor

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
        self.mode: str | None = None  # scanning mode, None when idle
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
    def start(self, mode: str = "standard") -> None:
        """Motor on, scan started, the reader thread running."""
        if mode not in ("standard", "express"):
            raise ValueError(f"scan mode must be 'standard' or 'express', got {mode!r}")
        if self._thread is not None:
            raise LidarError("already scanning")
        self.start_motor()
        parser = self._start_scan(mode)
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

    def _start_scan(self, mode: str):
        """Send SCAN / EXPRESS_SCAN, read the descriptor, return the stream parser."""
        self.mode = None
        with self._lock:
            self.serial.reset_input_buffer()
            if mode == "standard":
                self.send(p.SCAN)
            else:
                self.send(p.EXPRESS_SCAN, p.express_payload(0))
            d, buffer = self._await_descriptor(f"{mode} scan", time.monotonic() + self.timeout)
        self.rotations.reset()
        if d.answer_type == p.ANS_NODE:
            parser = NodeStream(self.rotations, self.stats)
        elif d.answer_type in (p.ANS_CAPSULE, p.ANS_DENSE):
            parser = CapsuleStream(self.rotations, d.answer_type == p.ANS_DENSE, self.stats)
        else:
            raise LidarError(f"{mode} scan: answer type 0x{d.answer_type:02X} is not supported "
                             "(0x81 nodes, 0x82 express and 0x85 dense capsules are)")
        parser.feed(bytes(buffer))
        self.mode = mode
        return parser

    def _read_loop(self, mode: str, parser) -> None:
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
