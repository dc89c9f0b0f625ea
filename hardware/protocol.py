"""The RPLidar serial protocol as pure functions: bytes in, values out, and back (no I/O).

Byte layouts follow ``shared/reference/rplidar-protocol.md`` (section numbers B1–B9 below) and,
where sources disagree, Slamtec's SDK: the express capsule's angle offsets dθ are unsigned
(B5), the health error code is little-endian (B3), dense distances are little-endian (B6).
Angles are the scanner's: degrees, clockwise, 0 at the scanner's front.

The decoders return ``None`` for a malformed unit instead of raising; the stream parsers in
:mod:`hardware.stream` count those and resynchronise.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

SYNC = 0xA5
SYNC2 = 0x5A

# B1: commands.
STOP, RESET, SCAN, FORCE_SCAN = 0x25, 0x40, 0x20, 0x21
GET_INFO, GET_HEALTH, GET_SAMPLERATE = 0x50, 0x52, 0x59
EXPRESS_SCAN, HQ_SCAN, GET_LIDAR_CONF, SET_LIDAR_CONF = 0x82, 0x83, 0x84, 0x85
NEW_BAUDRATE_CONFIRM, HQ_MOTOR_SPEED_CTRL, SET_MOTOR_PWM, GET_ACC_BOARD_FLAG = 0x90, 0xA8, 0xF0, 0xFF
HAS_PAYLOAD = 0x80
DEFAULT_PWM = 660

# B2: answer types.
ANS_NODE, ANS_CAPSULE, ANS_HQ, ANS_ULTRA, ANS_DENSE, ANS_ULTRA_DENSE = 0x81, 0x82, 0x83, 0x84, 0x85, 0x86
ANS_INFO, ANS_HEALTH, ANS_SAMPLERATE, ANS_LIDAR_CONF, ANS_ACC_BOARD_FLAG = 0x04, 0x06, 0x15, 0x20, 0xFF
SINGLE, MULTIPLE = 0, 1
DESCRIPTOR_LEN = 7
NODE_LEN = 5
CAPSULE_LEN = 84  # legacy express and dense alike
INFO_LEN, HEALTH_LEN, SAMPLERATE_LEN = 20, 3, 4

# B3: GET_LIDAR_CONF types.
CONF_MODE_COUNT, CONF_US_PER_SAMPLE, CONF_MAX_DISTANCE = 0x70, 0x71, 0x74
CONF_ANSWER_TYPE, CONF_TYPICAL_MODE, CONF_MODE_NAME = 0x75, 0x7C, 0x7F

FULL_CIRCLE_Q6 = 360 << 6
FULL_CIRCLE_Q16 = 360 << 16
SYNTHETIC_QUALITY = 0x2F  # the SDK's quality (0x2F << 2 with the flag bits) for capsule samples


# ---------------------------------------------------------------------- B1 requests
def encode_request(command: int, payload: bytes = b"") -> bytes:
    """``A5 CMD`` or, for commands with the 0x80 flag, ``A5 CMD LEN PAYLOAD CHK``."""
    if not 0 <= command <= 0xFF:
        raise ValueError(f"command byte out of range: {command}")
    if not command & HAS_PAYLOAD:
        if payload:
            raise ValueError(f"command 0x{command:02X} takes no payload")
        return bytes((SYNC, command))
    if len(payload) > 255:
        raise ValueError(f"payload of {len(payload)} bytes exceeds 255")
    body = bytes((SYNC, command, len(payload))) + bytes(payload)
    return body + bytes((xor(body),))


def xor(data) -> int:
    c = 0
    for b in data:
        c ^= b
    return c


def decode_request(data: bytes, offset: int = 0):
    """A request at ``data[offset:]``: ``(command, payload, length)``, ``None`` if incomplete,
    or ``(None, None, 1)`` if the first byte cannot start one (skip it)."""
    if len(data) - offset < 2:
        return None
    if data[offset] != SYNC:
        return None, None, 1
    command = data[offset + 1]
    if not command & HAS_PAYLOAD:
        return command, b"", 2
    if len(data) - offset < 3:
        return None
    size = data[offset + 2]
    end = offset + 3 + size + 1
    if len(data) < end:
        return None
    if xor(data[offset : end - 1]) != data[end - 1]:
        return None, None, 1
    return command, bytes(data[offset + 3 : end - 1]), end - offset


def express_payload(working_mode: int = 0, flags: int = 0, param: int = 0) -> bytes:
    return struct.pack("<BHH", working_mode, flags, param)


def motor_pwm_payload(pwm: int) -> bytes:
    if not 0 <= pwm <= 1023:
        raise ValueError(f"PWM must be 0–1023, got {pwm}")
    return struct.pack("<H", pwm)


def motor_rpm_payload(rpm: int) -> bytes:
    if not 0 <= rpm <= 0xFFFF:
        raise ValueError(f"rpm must be 0–65535, got {rpm}")
    return struct.pack("<H", rpm)


def lidar_conf_payload(conf_type: int, mode: int | None = None) -> bytes:
    return struct.pack("<I", conf_type) + (b"" if mode is None else struct.pack("<H", mode))


# ---------------------------------------------------------------------- B2 descriptors
@dataclass(frozen=True)
class Descriptor:
    length: int  # bytes per packet (bits 0–29)
    mode: int  # SINGLE or MULTIPLE (bits 30–31)
    answer_type: int


def encode_descriptor(length: int, mode: int, answer_type: int) -> bytes:
    if not 0 <= length < (1 << 30) or mode not in (0, 1, 2, 3):
        raise ValueError(f"bad descriptor length {length} or mode {mode}")
    return bytes((SYNC, SYNC2)) + struct.pack("<I", length | (mode << 30)) + bytes((answer_type,))


def decode_descriptor(data) -> Descriptor | None:
    if len(data) < DESCRIPTOR_LEN or data[0] != SYNC or data[1] != SYNC2:
        return None
    word = struct.unpack_from("<I", bytes(data[2:6]))[0]
    return Descriptor(word & 0x3FFFFFFF, word >> 30, data[6])


# ---------------------------------------------------------------------- B3 single responses
@dataclass(frozen=True)
class DeviceInfo:
    model: int
    firmware_minor: int
    firmware_major: int
    hardware: int
    serial: bytes  # 16 bytes

    @property
    def major_model(self) -> int:
        return self.model >> 4

    @property
    def serial_hex(self) -> str:
        return self.serial.hex().upper()


def encode_info(info: DeviceInfo) -> bytes:
    if len(info.serial) != 16:
        raise ValueError("the serial number has 16 bytes")
    return bytes((info.model, info.firmware_minor, info.firmware_major, info.hardware)) + info.serial


def decode_info(data) -> DeviceInfo | None:
    if len(data) != INFO_LEN:
        return None
    return DeviceInfo(data[0], data[1], data[2], data[3], bytes(data[4:20]))


HEALTH_STATUS = {0: "ok", 1: "warning", 2: "error"}


def encode_health(status: int, error: int = 0) -> bytes:
    return struct.pack("<BH", status, error)


def decode_health(data) -> tuple[int, int] | None:
    """(status 0 ok / 1 warning / 2 error, error code) — little-endian as in the SDK."""
    if len(data) != HEALTH_LEN:
        return None
    return struct.unpack("<BH", bytes(data))


def encode_samplerate(standard_us: int, express_us: int) -> bytes:
    return struct.pack("<HH", standard_us, express_us)


def decode_samplerate(data) -> tuple[int, int] | None:
    """(µs per sample in standard mode, in express mode)."""
    if len(data) != SAMPLERATE_LEN:
        return None
    return struct.unpack("<HH", bytes(data))


def encode_lidar_conf(conf_type: int, value) -> bytes:
    """A GET_LIDAR_CONF reply: the type echoed, then its value in the type's encoding."""
    head = struct.pack("<I", conf_type)
    if conf_type in (CONF_MODE_COUNT, CONF_TYPICAL_MODE):
        return head + struct.pack("<H", value)
    if conf_type in (CONF_US_PER_SAMPLE, CONF_MAX_DISTANCE):
        return head + struct.pack("<I", round(value * 256))
    if conf_type == CONF_ANSWER_TYPE:
        return head + bytes((value,))
    if conf_type == CONF_MODE_NAME:
        return head + value.encode("ascii") + b"\0"
    raise ValueError(f"unknown LIDAR_CONF type 0x{conf_type:X}")


def decode_lidar_conf(data):
    """``(type, value)``: ints, floats for the q8 fields (µs, m), str for the name."""
    if len(data) < 4:
        return None
    conf_type = struct.unpack_from("<I", bytes(data[:4]))[0]
    rest = bytes(data[4:])
    try:
        if conf_type in (CONF_MODE_COUNT, CONF_TYPICAL_MODE):
            return conf_type, struct.unpack("<H", rest[:2])[0]
        if conf_type in (CONF_US_PER_SAMPLE, CONF_MAX_DISTANCE):
            return conf_type, struct.unpack("<I", rest[:4])[0] / 256.0
        if conf_type == CONF_ANSWER_TYPE:
            return conf_type, rest[0]
        if conf_type == CONF_MODE_NAME:
            return conf_type, rest.split(b"\0", 1)[0].decode("ascii", "replace")
    except (struct.error, IndexError):
        return None
    return conf_type, rest


# ---------------------------------------------------------------------- B4 standard node
def encode_node(quality: int, angle_q6: int, distance_q2: int, start: bool) -> bytes:
    """One 5-byte node: quality 0–63, angle in 1/64°, distance in 1/4 mm (0: invalid)."""
    if not (0 <= quality < 64 and 0 <= angle_q6 < 1 << 15 and 0 <= distance_q2 < 1 << 16):
        raise ValueError(f"node field out of range: {quality}, {angle_q6}, {distance_q2}")
    b0 = (quality << 2) | (0b01 if start else 0b10)
    return bytes((b0, ((angle_q6 & 0x7F) << 1) | 1, angle_q6 >> 7)) + struct.pack("<H", distance_q2)


def decode_node(data, offset: int = 0):
    """``(start, quality, angle_q6, distance_q2)`` or None when the flag bits are wrong."""
    b0, b1 = data[offset], data[offset + 1]
    if (b0 & 1) == ((b0 >> 1) & 1) or not b1 & 1:
        return None
    angle_q6 = (b1 >> 1) | (data[offset + 2] << 7)
    return bool(b0 & 1), b0 >> 2, angle_q6, data[offset + 3] | (data[offset + 4] << 8)


# ---------------------------------------------------------------------- B5/B6 capsules
def _capsule_header(start_angle_q6: int, start: bool, body: bytes) -> bytes:
    if not 0 <= start_angle_q6 < 1 << 15:
        raise ValueError(f"start angle out of range: {start_angle_q6}")
    word = struct.pack("<H", start_angle_q6 | (0x8000 if start else 0))
    chk = xor(word + body)
    return bytes((0xA0 | (chk & 0xF), 0x50 | (chk >> 4))) + word + body


def encode_express_capsule(start_angle_q6: int, start: bool, distances_mm, dtheta_q3) -> bytes:
    """A legacy express capsule (0x82): 32 distances (mm, < 16384) and their unsigned angle
    offsets dθ (1/8°, 0–63), in 16 cabins of two."""
    if len(distances_mm) != 32 or len(dtheta_q3) != 32:
        raise ValueError("an express capsule holds 32 samples")
    body = bytearray()
    for c in range(16):
        d1, d2 = int(distances_mm[2 * c]), int(distances_mm[2 * c + 1])
        a1, a2 = int(dtheta_q3[2 * c]), int(dtheta_q3[2 * c + 1])
        if not (0 <= d1 < 1 << 14 and 0 <= d2 < 1 << 14 and 0 <= a1 < 64 and 0 <= a2 < 64):
            raise ValueError(f"cabin {c} out of range: {d1}, {d2}, {a1}, {a2}")
        body += struct.pack("<HH", (d1 << 2) | (a1 >> 4), (d2 << 2) | (a2 >> 4))
        body.append((a1 & 0xF) | ((a2 & 0xF) << 4))
    return _capsule_header(start_angle_q6, start, bytes(body))


def encode_dense_capsule(start_angle_q6: int, start: bool, distances_mm) -> bytes:
    """A dense capsule (0x85): 40 distances in mm, u16 little-endian as in the SDK."""
    if len(distances_mm) != 40:
        raise ValueError("a dense capsule holds 40 samples")
    return _capsule_header(start_angle_q6, start, struct.pack("<40H", *(int(d) for d in distances_mm)))


def check_capsule(data, offset: int = 0) -> int:
    """0: a well-formed capsule at ``offset``; 1: bad sync nibbles; 2: checksum mismatch."""
    b0, b1 = data[offset], data[offset + 1]
    if b0 >> 4 != 0xA or b1 >> 4 != 0x5:
        return 1
    if xor(data[offset + 2 : offset + CAPSULE_LEN]) != ((b0 & 0xF) | ((b1 & 0xF) << 4)):
        return 2
    return 0


@dataclass(frozen=True)
class Capsule:
    start_angle_q6: int
    start: bool
    distances_mm: tuple  # 32 (express) or 40 (dense)
    dtheta_q3: tuple  # 32 offsets (express); () for dense


def decode_capsule(data, offset: int = 0, dense: bool = False) -> Capsule | None:
    """The fields of a well-formed capsule (``check_capsule`` == 0), else None."""
    if len(data) - offset < CAPSULE_LEN or check_capsule(data, offset):
        return None
    word = data[offset + 2] | (data[offset + 3] << 8)
    if dense:
        dist = struct.unpack_from("<40H", bytes(data[offset + 4 : offset + CAPSULE_LEN]))
        return Capsule(word & 0x7FFF, bool(word & 0x8000), dist, ())
    distances, offsets = [], []
    for c in range(16):
        p = offset + 4 + 5 * c
        u1 = data[p] | (data[p + 1] << 8)
        u2 = data[p + 2] | (data[p + 3] << 8)
        b4 = data[p + 4]
        distances += [u1 >> 2, u2 >> 2]
        offsets += [(b4 & 0xF) | ((u1 & 0x3) << 4), (b4 >> 4) | ((u2 & 0x3) << 4)]
    return Capsule(word & 0x7FFF, bool(word & 0x8000), tuple(distances), tuple(offsets))


def capsule_samples(previous: Capsule, current_start_angle_q6: int):
    """Samples of ``previous`` once the next capsule's start angle is known (B5, the SDK's
    fixed point): a list of ``(start_of_rotation, quality, angle_q6, distance_q2)``."""
    n = len(previous.distances_mm)
    prev_q8 = previous.start_angle_q6 << 2
    cur_q8 = current_start_angle_q6 << 2
    diff_q8 = cur_q8 - prev_q8
    if prev_q8 > cur_q8:
        diff_q8 += 360 << 8
    inc_q16 = (diff_q8 << 3) if n == 32 else (diff_q8 << 8) // n
    angle_q16 = prev_q8 << 8
    out = []
    for k in range(n):
        dist = previous.distances_mm[k]
        if n == 32:
            angle_q6 = (angle_q16 - (previous.dtheta_q3[k] << 13)) >> 10
        else:
            angle_q6 = angle_q16 >> 10
        angle_q6 %= FULL_CIRCLE_Q6
        start = ((angle_q16 + inc_q16) % FULL_CIRCLE_Q16) < inc_q16
        angle_q16 += inc_q16
        out.append((start, SYNTHETIC_QUALITY if dist > 0 else 0, angle_q6, dist << 2))
    return out
