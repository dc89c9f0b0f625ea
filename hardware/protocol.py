"""The RPLidar serial protocol as pure functions: bytes in, values out, and back (no I/O).

Byte layouts follow ``shared/reference/rplidar-protocol.md`` (section numbers B1–B9 below) and,
where sources disagree, Slamtec's SDK: the express capsule's angle offsets dθ are unsigned
(B5), the health error code is little-endian (B3), dense distances are little-endian (B6).
Angles are the scanner's: degrees, clockwise, 0 at the scanner's front.

The decoders return ``None`` for a malformed unit instead of raising; the stream parsers in
:mod:`swarmslam.hardware.stream` count those and resynchronise.
"""

from __future__ import annotations

import struct
import zlib
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
ULTRA_LEN, ULTRA_DENSE_LEN, HQ_LEN = 132, 170, 781  # B6
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


# B7: baud negotiation (S/A-series firmware that supports it, as the SDK's
# negotiateSerialBaudRate): the host, already at the new rate, sends AUTOBAUD_MAGIC bytes until
# the device answers with the rate it measured (u32), then confirms with NEW_BAUDRATE_CONFIRM
# {flag u16 = BAUD_CONFIRM_FLAG, required bps u32, param u16}; unconfirmed, the device reverts.
AUTOBAUD_MAGIC = 0x41
BAUD_CONFIRM_FLAG = 0x5F5F


def baud_confirm_payload(bps: int) -> bytes:
    return struct.pack("<HIH", BAUD_CONFIRM_FLAG, bps, 0)


def decode_baud_confirm(payload: bytes) -> int | None:
    """The confirmed rate, or None if the payload is not a confirmation."""
    if len(payload) != 8:
        return None
    flag, bps, _ = struct.unpack("<HIH", payload)
    return bps if flag == BAUD_CONFIRM_FLAG else None


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
def _capsule_header(start_angle_q6: int, start: bool, body: bytes,
                    prefix: bytes = b"") -> bytes:
    """Sync nibbles and checksum, then ``prefix`` (the ultra-dense capsule's time stamp and
    status), the start angle with its flag, and ``body``; the checksum covers all but the
    first two bytes."""
    if not 0 <= start_angle_q6 < 1 << 15:
        raise ValueError(f"start angle out of range: {start_angle_q6}")
    word = prefix + struct.pack("<H", start_angle_q6 | (0x8000 if start else 0))
    chk = xor(word + body)
    return bytes((0xA0 | (chk & 0xF), 0x50 | (chk >> 4))) + word + body


def _start_angles_q8(previous_q6: int, current_q6: int) -> tuple[int, int]:
    """A capsule's start angle and the angle to the next capsule's, Q8 degrees (B5: a
    difference past 360° wraps)."""
    prev_q8, cur_q8 = previous_q6 << 2, current_q6 << 2
    return prev_q8, cur_q8 - prev_q8 + (360 << 8 if prev_q8 > cur_q8 else 0)


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


def check_capsule(data, offset: int = 0, length: int = CAPSULE_LEN) -> int:
    """0: a well-formed capsule of ``length`` bytes at ``offset``; 1: bad sync nibbles;
    2: checksum mismatch (every capsule format sums its bytes from the third on)."""
    b0, b1 = data[offset], data[offset + 1]
    if b0 >> 4 != 0xA or b1 >> 4 != 0x5:
        return 1
    if xor(data[offset + 2 : offset + length]) != ((b0 & 0xF) | ((b1 & 0xF) << 4)):
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
    prev_q8, diff_q8 = _start_angles_q8(previous.start_angle_q6, current_start_angle_q6)
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


# ---------------------------------------------------------------------- B6 ultra capsules
# Ultra (0x84, A2/A3 "Boost", "Sensitivity", "Stability"): header, then 32 u32 cabins of three
# samples — a 12-bit major distance in a variable-bit scale and two signed 10-bit predictions
# from it and from the next cabin's major. Angles carry no offsets: the SDK models the optics
# (a distance-dependent offset of about 8°), and so do we, in its fixed point.
VBS_LEVELS = ((3328, 4, 1 << 14), (1792, 3, 1 << 12), (1280, 2, 1 << 11), (512, 1, 1 << 9),
              (0, 0, 0))  # (scaled base, scale level, distance base) from ×16 down to ×1
PREDICT_INVALID = (0x1FF, -0x200)  # a prediction with these values means "no return"


def varbitscale_decode(scaled: int) -> tuple[int, int]:
    """A 12-bit major distance → (mm, scale level)."""
    for base, level, target in VBS_LEVELS:
        if scaled >= base:
            return target + ((scaled - base) << level), level
    return 0, 0


def varbitscale_encode(mm: int) -> int:
    """The 12-bit code whose decoding is nearest ``mm`` (from below: codes truncate)."""
    for base, level, target in VBS_LEVELS:
        if mm >= target:
            return min(base + ((mm - target) >> level), 0xFFF)
    return 0


def _signed10(v: int) -> int:
    v &= 0x3FF
    return v - 0x400 if v & 0x200 else v


def encode_ultra_capsule(start_angle_q6: int, start: bool, distances_mm,
                         next_first_mm: int) -> bytes:
    """An ultra capsule (0x84): 96 distances (mm); ``next_first_mm`` is the next capsule's
    first sample, the base the last cabin's third sample is predicted from. A sample whose
    prediction does not fit 10 bits is sent as "no return", as the device does at an edge."""
    if len(distances_mm) != 96:
        raise ValueError("an ultra capsule holds 96 samples")
    majors = [varbitscale_encode(int(distances_mm[3 * c])) for c in range(32)]
    majors.append(varbitscale_encode(int(next_first_mm)))
    body = bytearray()
    for c in range(32):
        base1, level1 = varbitscale_decode(majors[c])
        base2, level2 = varbitscale_decode(majors[c + 1])
        if base1 == 0 and base2:
            base1, level1 = base2, level2
        predictions = []
        for d, base, level in ((distances_mm[3 * c + 1], base1, level1),
                               (distances_mm[3 * c + 2], base2, level2)):
            d = int(d)
            q = round((d - base) / (1 << level)) if d > 0 else PREDICT_INVALID[0]
            if d <= 0 or not -0x200 < q < 0x1FF or base + (q << level) <= 0:
                q = PREDICT_INVALID[0]
            predictions.append(q & 0x3FF)
        body += struct.pack("<I", majors[c] | (predictions[0] << 12) | (predictions[1] << 22))
    return _capsule_header(start_angle_q6, start, bytes(body))


def decode_ultra_capsule(data, offset: int = 0) -> Capsule | None:
    """An ultra capsule's start angle, flag and 32 raw cabin words (``distances_mm``)."""
    if len(data) - offset < ULTRA_LEN or check_capsule(data, offset, ULTRA_LEN):
        return None
    word = data[offset + 2] | (data[offset + 3] << 8)
    cabins = struct.unpack_from("<32I", bytes(data[offset + 4 : offset + ULTRA_LEN]))
    return Capsule(word & 0x7FFF, bool(word & 0x8000), cabins, ())


_DEFAULT_OPTICAL_Q16 = int(7.5 * 3.1415926535 * (1 << 16) / 180.0)  # 7.5°, rad in Q16
_NEAR_OPTICAL_Q16 = int(8 * 3.1415926535 * (1 << 16) / 180)  # 8°


def _ultra_offset_q16(distance_q2: int) -> int:
    """The optical angle offset of an ultra sample, in degrees Q16 as the SDK computes it
    (a rational fit in the distance; integer steps as in its fixed point)."""
    offset = _DEFAULT_OPTICAL_Q16
    if distance_q2 >= 50 * 4:
        k2 = 98361 // distance_q2
        offset = _NEAR_OPTICAL_Q16 - (k2 << 6) - (k2 * k2 * k2) // 98304
    return int(offset * 180 / 3.14159265)


def ultra_capsule_samples(previous: Capsule, current: Capsule):
    """The 96 samples of ``previous`` once ``current`` arrived (its start angle and first
    cabin's major): ``(start_of_rotation, quality, angle_q6, distance_q2)``."""
    prev_q8, diff_q8 = _start_angles_q8(previous.start_angle_q6, current.start_angle_q6)
    inc_q16 = (diff_q8 << 3) // 3
    angle_q16 = prev_q8 << 8
    cabins = previous.distances_mm
    out = []
    for c in range(32):
        word = cabins[c]
        major, level1 = varbitscale_decode(word & 0xFFF)
        nxt = cabins[c + 1] if c < 31 else current.distances_mm[0]
        major2, level2 = varbitscale_decode(nxt & 0xFFF)
        base1 = major
        if not major and major2:
            base1, level1 = major2, level2
        p1, p2 = _signed10(word >> 12), _signed10(word >> 22)
        dist_q2 = [major << 2,
                   0 if p1 in PREDICT_INVALID else ((p1 << level1) + base1) << 2,
                   0 if p2 in PREDICT_INVALID else ((p2 << level2) + major2) << 2]
        for d in dist_q2:
            start = ((angle_q16 + inc_q16) % FULL_CIRCLE_Q16) < inc_q16
            angle_q6 = ((angle_q16 - _ultra_offset_q16(d)) >> 10) % FULL_CIRCLE_Q6
            angle_q16 += inc_q16
            out.append((start, SYNTHETIC_QUALITY if d else 0, angle_q6, d))
    return out


# Ultra-dense (0x86): header, a u32 device time stamp, a u16 status, the start angle, then 32
# cabins of two 20-bit samples (two u16 low parts, one byte of high nibbles). Each sample is a
# 2-bit scale and a distance and quality sharing the other 18 bits: the nearer, the finer.
ULTRA_DENSE_SCALES = ((0, 2, 10), (2046, 3, 11), (8187, 4, 12), (24567, 5, 13))  # base mm,
# mm per step, distance bits; the quality gets the bits left of 18


def encode_ultra_dense_capsule(start_angle_q6: int, start: bool, distances_mm,
                               quality: int = 188, time_stamp: int = 0) -> bytes:
    """An ultra-dense capsule (0x86): 64 distances (mm), one quality (0–255) for all."""
    if len(distances_mm) != 64:
        raise ValueError("an ultra-dense capsule holds 64 samples")
    values = []
    for d in distances_mm:
        d = max(int(d), 0)
        scale = 0 if d <= 2046 else 1 if d <= 8187 else 2 if d <= 24567 else 3
        base, step, bits = ULTRA_DENSE_SCALES[scale]
        steps = min(round((d - base) / step), (1 << bits) - 1)
        q = (quality >> scale) if d else 0
        values.append((q << (bits + 2)) | (steps << 2) | scale)
    body = bytearray()
    for c in range(32):
        a, b = values[2 * c], values[2 * c + 1]
        body += struct.pack("<HHB", a & 0xFFFF, b & 0xFFFF, (a >> 16) | ((b >> 16) << 4))
    return _capsule_header(start_angle_q6, start, bytes(body),
                           prefix=struct.pack("<IH", time_stamp & 0xFFFFFFFF, 0))


def decode_ultra_dense_capsule(data, offset: int = 0) -> Capsule | None:
    """An ultra-dense capsule's start angle, flag and 64 raw 20-bit samples."""
    if len(data) - offset < ULTRA_DENSE_LEN or check_capsule(data, offset, ULTRA_DENSE_LEN):
        return None
    word = data[offset + 8] | (data[offset + 9] << 8)
    values = []
    for c in range(32):
        lo1, lo2, hi = struct.unpack_from("<HHB", bytes(data[offset + 10 + 5 * c:
                                                             offset + 15 + 5 * c]))
        values += [lo1 | ((hi & 0xF) << 16), lo2 | ((hi >> 4) << 16)]
    return Capsule(word & 0x7FFF, bool(word & 0x8000), tuple(values), ())


def ultra_dense_capsule_samples(previous: Capsule, current_start_angle_q6: int, last: list):
    """The 64 samples of ``previous``; ``last`` carries ``[distance_q2, start]`` of the sample
    before, across calls: the finest scale averages a distance within 2 mm of the one before
    with it, and a rotation starts once (the SDK's rule)."""
    prev_q8, diff_q8 = _start_angles_q8(previous.start_angle_q6, current_start_angle_q6)
    inc_q16 = (diff_q8 << 8) // 64
    angle_q16 = prev_q8 << 8
    out = []
    for v in previous.distances_mm:
        scale = v & 0x3
        base, step, bits = ULTRA_DENSE_SCALES[scale]
        quality = (v >> (bits + 2)) << scale
        dist_q2 = ((v >> 2) & ((1 << bits) - 1)) * step * 4 + (base << 2)
        if scale == 0 and last[0] and abs(dist_q2 - last[0]) <= 8:
            dist_q2 = (dist_q2 + last[0]) >> 1
        last[0] = dist_q2
        start = ((angle_q16 + inc_q16) % FULL_CIRCLE_Q16) < (inc_q16 << 1)
        start = start and not last[1]  # the window spans two samples: the first of them
        last[1] = start
        out.append((start, quality, (angle_q16 >> 10) % FULL_CIRCLE_Q6, dist_q2))
        angle_q16 += inc_q16
    return out


# HQ (0x83): sync byte A5, u64 time stamp, 96 nodes {angle_z_q14 u16 (90° = 16384),
# dist_mm_q2 u32, quality u8, flag u8 (bit 0: a rotation starts)}, then a CRC-32 (IEEE, the
# SDK's: over the 777 bytes zero-padded by 1-4 bytes to a multiple of four).
HQ_NODES = 96


def hq_crc(data: bytes) -> int:
    return zlib.crc32(bytes(data) + bytes(4 - (len(data) & 3)))


def encode_hq_capsule(nodes, time_stamp: int = 0) -> bytes:
    """An HQ capsule from 96 ``(angle_z_q14, dist_mm_q2, quality, start)``."""
    if len(nodes) != HQ_NODES:
        raise ValueError(f"an HQ capsule holds {HQ_NODES} nodes")
    body = bytearray((SYNC,)) + struct.pack("<Q", time_stamp)
    for z, d, q, start in nodes:
        body += struct.pack("<HIBB", z, d, q, 1 if start else 2)
    return bytes(body) + struct.pack("<I", hq_crc(body))


def decode_hq_capsule(data, offset: int = 0):
    """The 96 nodes ``(start, quality, angle_q6, distance_q2)`` of a well-formed HQ capsule
    (the angle in Q6 degrees as a float: exact), else None."""
    if len(data) - offset < HQ_LEN or data[offset] != SYNC:
        return None
    raw = bytes(data[offset : offset + HQ_LEN])
    if struct.unpack_from("<I", raw, HQ_LEN - 4)[0] != hq_crc(raw[: HQ_LEN - 4]):
        return None
    out = []
    for k in range(HQ_NODES):
        z, d, q, flag = struct.unpack_from("<HIBB", raw, 9 + 8 * k)
        out.append((bool(flag & 1), q, z * 90 * 64 / 16384, d))
    return out
