"""The RPLidar codec: round trips (hypothesis), the protocol note's worked examples, and
damaged streams (fuzz): nothing raises, every good packet after the damage is decoded."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmslam.hardware import protocol as p
from swarmslam.hardware.stream import CapsuleStream, NodeStream, StreamStats, find_descriptor


class Sink:
    def __init__(self):
        self.samples = []

    def add(self, start, quality, angle_q6, distance_q2):
        self.samples.append((start, quality, angle_q6, distance_q2))


# ---------------------------------------------------------------------- worked examples (B1, B2)
def test_requests_and_descriptors_match_the_protocol_note():
    assert p.encode_request(p.GET_INFO) == bytes.fromhex("A550")
    assert p.encode_request(p.EXPRESS_SCAN, p.express_payload(0)) == bytes.fromhex("A582050000000000 22".replace(" ", ""))
    assert p.encode_request(p.SET_MOTOR_PWM, p.motor_pwm_payload(660)) == bytes.fromhex("A5F0029402C1")
    assert p.encode_descriptor(5, p.MULTIPLE, p.ANS_NODE) == bytes.fromhex("A55A0500004081")
    assert p.encode_descriptor(84, p.MULTIPLE, p.ANS_CAPSULE) == bytes.fromhex("A55A5400004082")
    assert p.encode_descriptor(20, p.SINGLE, p.ANS_INFO) == bytes.fromhex("A55A1400000004")
    with pytest.raises(ValueError, match="no payload"):
        p.encode_request(p.GET_INFO, b"\x01")


@given(st.integers(0x80, 0xFF), st.binary(max_size=40))
def test_request_round_trip(command, payload):
    data = p.encode_request(command, payload)
    assert p.decode_request(data) == (command, payload, len(data))
    assert p.decode_request(data[:-1]) is None  # incomplete: wait for more
    damaged = data[:-1] + bytes([data[-1] ^ 0x01])
    assert p.decode_request(damaged) == (None, None, 1)


@given(st.integers(0, (1 << 30) - 1), st.integers(0, 1), st.integers(0, 255))
def test_descriptor_round_trip(length, mode, answer):
    d = p.decode_descriptor(p.encode_descriptor(length, mode, answer))
    assert (d.length, d.mode, d.answer_type) == (length, mode, answer)


@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255),
       st.binary(min_size=16, max_size=16), st.integers(0, 2), st.integers(0, 0xFFFF),
       st.integers(0, 0xFFFF), st.integers(0, 0xFFFF))
def test_single_responses_round_trip(model, fw_minor, fw_major, hw, serial, status, error, t1, t2):
    info = p.DeviceInfo(model, fw_minor, fw_major, hw, serial)
    assert p.decode_info(p.encode_info(info)) == info
    assert p.decode_health(p.encode_health(status, error)) == (status, error)
    assert p.decode_samplerate(p.encode_samplerate(t1, t2)) == (t1, t2)


def test_health_error_code_is_little_endian_as_in_the_sdk():
    assert p.decode_health(bytes([2, 0x34, 0x12])) == (2, 0x1234)


@pytest.mark.parametrize("conf_type,value", [
    (p.CONF_MODE_COUNT, 5), (p.CONF_TYPICAL_MODE, 3), (p.CONF_US_PER_SAMPLE, 508.0),
    (p.CONF_US_PER_SAMPLE, 126.5), (p.CONF_MAX_DISTANCE, 12.0), (p.CONF_ANSWER_TYPE, 0x84),
    (p.CONF_MODE_NAME, "Sensitivity")])
def test_lidar_conf_round_trip(conf_type, value):
    assert p.decode_lidar_conf(p.encode_lidar_conf(conf_type, value)) == (conf_type, value)


# ---------------------------------------------------------------------- nodes (B4)
@given(st.integers(0, 63), st.integers(0, 360 * 64 - 1), st.integers(0, 0xFFFF), st.booleans())
def test_node_round_trip(quality, angle_q6, distance_q2, start):
    node = p.encode_node(quality, angle_q6, distance_q2, start)
    assert len(node) == 5
    assert p.decode_node(node) == (start, quality, angle_q6, distance_q2)


def test_node_with_bad_flags_is_refused_not_raised():
    node = bytearray(p.encode_node(10, 100, 400, False))
    node[0] |= 0b11  # S == ¬S
    assert p.decode_node(node) is None
    node = bytearray(p.encode_node(10, 100, 400, False))
    node[1] &= 0xFE  # C = 0
    assert p.decode_node(node) is None


# ---------------------------------------------------------------------- capsules (B5, B6)
distances32 = st.lists(st.integers(0, (1 << 14) - 1), min_size=32, max_size=32)
offsets32 = st.lists(st.integers(0, 63), min_size=32, max_size=32)


@given(st.integers(0, 360 * 64 - 1), st.booleans(), distances32, offsets32)
def test_express_capsule_round_trip(start_q6, start, distances, offsets):
    data = p.encode_express_capsule(start_q6, start, distances, offsets)
    assert len(data) == 84 and p.check_capsule(data) == 0
    c = p.decode_capsule(data)
    assert (c.start_angle_q6, c.start, list(c.distances_mm), list(c.dtheta_q3)) == \
        (start_q6, start, distances, offsets)


@given(st.integers(0, 360 * 64 - 1), st.booleans(),
       st.lists(st.integers(0, 0xFFFF), min_size=40, max_size=40))
def test_dense_capsule_round_trip(start_q6, start, distances):
    c = p.decode_capsule(p.encode_dense_capsule(start_q6, start, distances), dense=True)
    assert (c.start_angle_q6, c.start, list(c.distances_mm)) == (start_q6, start, distances)


@given(st.integers(0, 360 * 64 - 1), st.integers(1, 60 * 64), offsets32)
def test_express_angles_interpolate_between_two_capsules(start_q6, delta_q6, offsets):
    """θk = ω(i) + Δ·k/32 − dθk (B5), within the fixed point's 1/64° and wrapped to [0, 360)."""
    c = p.Capsule(start_q6, False, tuple(range(1, 33)), tuple(offsets))
    following = (start_q6 + delta_q6) % (360 * 64)
    samples = p.capsule_samples(c, following)
    assert [s[3] for s in samples] == [4 * d for d in range(1, 33)]
    for k, (_, quality, angle_q6, _) in enumerate(samples):
        expected = (start_q6 + delta_q6 * k / 32 - offsets[k] * 64 / 8) % (360 * 64)
        diff = (angle_q6 - expected + 180 * 64) % (360 * 64) - 180 * 64
        assert abs(diff) <= 1.0, (k, angle_q6, expected)
        assert quality == p.SYNTHETIC_QUALITY
    # the new-rotation flag marks exactly the samples whose nominal angle crossed 0°
    crossed = [(start_q6 + delta_q6 * (k + 1) / 32) >= 360 * 64 > (start_q6 + delta_q6 * k / 32)
               for k in range(32)]
    flags = [s[0] for s in samples]
    assert sum(flags) == sum(crossed)


def test_capsule_damage_is_reported_by_kind():
    good = p.encode_express_capsule(100, False, [500] * 32, [0] * 32)
    bad_sync = bytes([good[0] ^ 0x80]) + good[1:]
    bad_sum = good[:50] + bytes([good[50] ^ 0x04]) + good[51:]
    assert p.check_capsule(good) == 0
    assert p.check_capsule(bad_sync) == 1
    assert p.check_capsule(bad_sum) == 2
    assert p.decode_capsule(bad_sum) is None


# ---------------------------------------------------------------------- streams and damage
def node_stream(count, seed=0):
    """A plausible standard-scan stream: angles rising, a new rotation every 360 nodes."""
    rng = np.random.default_rng(seed)
    nodes, expected = [], []
    for k in range(count):
        angle = (k % 360) * 64 + int(rng.integers(0, 32))
        dist = int(rng.integers(0, 40000))
        node = (k % 360 == 0, 47, angle, dist)
        nodes.append(p.encode_node(47, angle, dist, node[0]))
        expected.append(node)
    return nodes, expected


def capsule_stream(count, dense=False, seed=0):
    rng = np.random.default_rng(seed)
    n = 40 if dense else 32
    step = 32 * 64 if not dense else 40 * 64  # 1° per sample
    out = []
    for k in range(count):
        start = (k * step) % (360 * 64)
        d = [int(v) for v in rng.integers(1, 8000, n)]
        if dense:
            out.append(p.encode_dense_capsule(start, k == 0, d))
        else:
            out.append(p.encode_express_capsule(start, k == 0, d, [int(v) for v in rng.integers(0, 16, n)]))
    return out


@given(st.binary(max_size=3000), st.integers(1, 64))
def test_random_bytes_never_raise(data, chunk):
    for parser in (NodeStream(Sink()), CapsuleStream(Sink()), CapsuleStream(Sink(), dense=True)):
        for i in range(0, len(data), chunk):
            parser.feed(data[i : i + chunk])
    buffer = bytearray(data)
    find_descriptor(buffer, StreamStats())


# Damage is random, so these fuzz tests run a fixed list of seeded streams (200 each, chunk
# sizes 1–97 bytes) rather than hypothesis's search: a rare false sync that the parsers cannot
# rule out (see hardware/stream.py for the rates) must not make CI flaky, and the cases must
# not depend on the hypothesis version installed.
FUZZ_CASES = [(seed, 1 + (seed * 37) % 97) for seed in range(200)]


@pytest.mark.parametrize("seed,chunk", FUZZ_CASES[:100])
def test_nodes_after_garbage_are_decoded(seed, chunk):
    """Standard nodes have no checksum, so a false node inside garbage can pass every check;
    the look-ahead resync makes that rare (0.28% of bursts over 400 seeded streams), and what
    it costs are the nodes right after the burst (all but one of 28 lost nodes there)."""
    rng = np.random.default_rng(seed)
    nodes, expected = node_stream(440, seed)  # the last 40 only close the stream
    data = bytearray()
    bursts = []
    for k, node in enumerate(nodes):
        if k < 400 and (k in (50, 51, 200) or rng.random() < 0.02):
            data += rng.integers(0, 256, int(rng.integers(1, 12)), dtype=np.uint8).tobytes()
            bursts.append(k)
        data += node
    sink, stats = Sink(), StreamStats()
    parser = NodeStream(sink, stats)
    for i in range(0, len(data), chunk):
        parser.feed(bytes(data[i : i + chunk]))
    got = set(sink.samples)
    missed = [k for k, node in enumerate(expected[:400]) if node not in got]
    assert all(any(0 <= k - j <= 2 for j in bursts) for k in missed), (missed, bursts)
    assert len(missed) <= 6, (missed, bursts)
    assert stats.resyncs >= 1 and stats.dropped_bytes >= len(bursts)


@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("seed,chunk", FUZZ_CASES)
def test_capsules_after_garbage_and_corruption_are_decoded(dense, seed, chunk):
    rng = np.random.default_rng(seed)
    capsules = capsule_stream(64, dense, seed)  # the last four only close the stream
    data, broken, bursts = bytearray(), set(), 0
    for k, c in enumerate(capsules):
        if 0 < k < 60 and rng.random() < 0.1:  # garbage before the capsule: it must survive
            bursts += 1
            data += rng.integers(0, 256, int(rng.integers(1, 30)), dtype=np.uint8).tobytes()
        if 0 < k < 60 and rng.random() < 0.1:  # a corrupted capsule: dropped, and its predecessor
            c = bytearray(c)
            c[int(rng.integers(4, 84))] ^= 1 << int(rng.integers(8))
            broken.add(k)
        data += c
    sink, stats = Sink(), StreamStats()
    parser = CapsuleStream(sink, dense, stats)
    for i in range(0, len(data), chunk):
        parser.feed(bytes(data[i : i + chunk]))
    # Each corrupted capsule is counted, give or take the false syncs garbage can bring.
    assert len(broken) - bursts <= stats.checksum_errors <= len(broken) + bursts
    clean_sink = Sink()
    clean = CapsuleStream(clean_sink, dense)
    for c in capsules:
        clean.feed(c)
    n = 40 if dense else 32
    # Capsule k's samples are decoded once k+1 arrives (capsule 0's too: S = 1 only starts
    # the chain). A corrupted capsule costs itself and its predecessor; garbage costs nothing,
    # except that a capsule between a false sync in garbage and a corrupted capsule cannot be
    # told from a false one (so the capsule before it loses its successor's angle too).
    lost = {j for k in broken for j in (k - 2, k - 1, k)}
    got = set(sink.samples)
    for k in range(61):
        part = clean_sink.samples[n * k : n * (k + 1)]
        if k not in lost:
            assert all(s in got for s in part), (k, sorted(broken))
    assert got <= set(clean_sink.samples)  # nothing decoded that was not sent


@given(st.lists(st.integers(150, 12000), min_size=1, max_size=1), st.integers(0, 300))
def test_ultra_capsule_distances_survive_their_variable_scale(first, start_q6):
    # a smooth wall: every sample predictable from its cabin's major, within the scale's step
    d = (first[0] + 3 * np.arange(97)).astype(int)
    this = p.decode_ultra_capsule(p.encode_ultra_capsule(start_q6, False, d[:96], int(d[96])))
    after = p.decode_ultra_capsule(p.encode_ultra_capsule(start_q6 + 600, False, d[96:].tolist()
                                                          * 96, int(d[96])))
    samples = p.ultra_capsule_samples(this, after)
    got = np.array([s[3] / 4.0 for s in samples])
    step = np.array([p.varbitscale_decode(p.varbitscale_encode(int(v)))[1] for v in d[:96]])
    assert np.all(np.abs(got - d[:96]) <= 2.0 ** (step + 1))  # a truncated major, a rounded step
    # the optical model: a sample lies behind the head's angle by an offset that grows with
    # the distance (negative very near) towards 8°
    heads = (start_q6 + np.arange(96) * 600 / 96) / 64.0
    offsets = (heads - np.array([s[2] / 64.0 for s in samples]) + 180) % 360 - 180
    assert np.all((offsets > -2.0) & (offsets < 8.1))
    assert np.all(np.diff(offsets[got > 0]) > -0.05)  # farther, never less (but rounding)
    assert np.all(offsets[d[:96] >= 3000] > 7.0)


def test_ultra_dense_and_hq_capsules_round_trip_and_refuse_damage():
    d = np.r_[np.arange(0, 2000, 62), np.arange(2100, 30000, 900)][:64]
    capsule = p.encode_ultra_dense_capsule(100, True, d)
    assert len(capsule) == p.ULTRA_DENSE_LEN and p.check_capsule(capsule, 0, p.ULTRA_DENSE_LEN) == 0
    got = [s[3] / 4.0 for s in p.ultra_dense_capsule_samples(
        p.decode_ultra_dense_capsule(capsule), 200, [0, False])]
    assert np.all(np.abs(np.array(got) - d) <= 2.5)  # 2, 3, 4, 5 mm steps by range
    nodes = [(k * 170, 4000 + k, 188, k == 0) for k in range(p.HQ_NODES)]
    hq = p.encode_hq_capsule(nodes, time_stamp=7)
    assert len(hq) == p.HQ_LEN
    assert [n[3] for n in p.decode_hq_capsule(hq)] == [4000 + k for k in range(p.HQ_NODES)]
    damaged = bytearray(hq)
    damaged[100] ^= 0x10
    assert p.decode_hq_capsule(bytes(damaged)) is None  # the CRC-32 catches it


def test_an_hq_stream_resynchronises_after_garbage_and_damage():
    from swarmslam.hardware.stream import HqStream

    nodes = [(k * 170, 4000 + k, 188, k == 0) for k in range(p.HQ_NODES)]
    good = p.encode_hq_capsule(nodes)
    broken = bytearray(good)
    broken[300] ^= 0xFF
    sink, stats = Sink(), StreamStats()
    stream = HqStream(sink, stats)
    for chunk in (good, bytes([p.SYNC, 1, 2, 3, 0xA5] * 5), bytes(broken), good):
        stream.feed(chunk)
    stream.feed(good)  # the last capsule is in once the next one's bytes arrive too
    assert len(sink.samples) == 3 * p.HQ_NODES
    assert stats.checksum_errors >= 1 and stats.resyncs >= 1
