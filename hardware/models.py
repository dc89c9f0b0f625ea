"""What differs between scanner models: baud rate, motor control, rates (protocol note B7, B8)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ScanMode:
    """One scan mode as GET_LIDAR_CONF describes it (B3)."""

    id: int
    name: str
    answer_type: int  # 0x81 nodes, 0x82 express, 0x83 HQ, 0x84 ultra, 0x85 dense, 0x86 ultra-dense
    us_per_sample: float
    max_distance: float  # m


_A_SERIES = (  # the A-series enumeration in the protocol note (B3): ultra capsules for Boost,
    # Sensitivity (the typical mode) and Stability
    ("Standard", 0x81, 508.0), ("Express", 0x82, 254.0), ("Boost", 0x84, 127.0),
    ("Sensitivity", 0x84, 127.0), ("Stability", 0x84, 201.0))


def _modes(table, max_distance):
    return tuple(ScanMode(k, name, ans, us, max_distance) for k, (name, ans, us) in
                 enumerate(table))


@dataclass(frozen=True)
class Model:
    name: str
    baud: int
    motor: str  # "dtr" (A1), "pwm" (A2/A3, accessory board), "rpm" (S-series, C1)
    major_id: int  # GET_INFO model >> 4
    express_answer: int  # answer type of express mode 0 on this model
    samples_per_second: int  # typical in express mode (standard: 508 µs per sample)
    scan_hz: float  # typical rotation rate
    max_range: float  # m
    modes: tuple = ()  # ScanMode, by id
    typical: int = 1  # the typical mode's id (what Slamtec's SDK starts)
    bauds: tuple = ()  # other baud rates the model switches to (B7), besides ``baud``

    @property
    def max_samples_per_second(self) -> int:
        """The fastest of its modes: what a rotation's buffers must hold at ``scan_hz``."""
        return int(round(max([self.samples_per_second]
                             + [1e6 / m.us_per_sample for m in self.modes])))

    def mode(self, key) -> ScanMode:
        """A scan mode by id, name (any case) or "typical"."""
        if key == "typical":
            key = self.typical
        for m in self.modes:
            if m.id == key or (isinstance(key, str) and m.name.lower() == key.lower()):
                return m
        names = ", ".join(m.name for m in self.modes)
        raise ValueError(f"the {self.name.upper()} has no scan mode {key!r} (it has {names}, "
                         f"or 'typical')")


MODELS = {
    "a1": Model("a1", 115200, "dtr", 1, 0x82, 4000, 5.5, 12.0,
                _modes(_A_SERIES[:2], 12.0), typical=1),
    "a2": Model("a2", 115200, "pwm", 2, 0x82, 4000, 10.0, 12.0,
                _modes(_A_SERIES, 12.0), typical=3, bauds=(256000,)),
    "a3": Model("a3", 256000, "pwm", 3, 0x82, 10000, 10.0, 25.0,
                _modes((("Standard", 0x81, 508.0), ("Express", 0x82, 254.0),
                        ("Boost", 0x84, 63.0), ("Sensitivity", 0x84, 63.0),
                        ("Stability", 0x84, 100.0)), 25.0), typical=3),
    "s1": Model("s1", 256000, "rpm", 6, 0x85, 9200, 10.0, 40.0,
                _modes((("Standard", 0x81, 108.0), ("DenseBoost", 0x85, 108.0)), 40.0),
                typical=1),
    # The S2's Standard mode at 10 kHz fits its 1 Mbaud link (5 bytes a node); DenseBoost
    # packs 32 kHz in dense capsules. HQ and UltraDense are the answers the SDK decodes for
    # newer firmware; which model sends them is not in our reference: the emulator offers
    # them here so that both decoders are tested against Slamtec's.
    "s2": Model("s2", 1000000, "rpm", 7, 0x85, 32000, 10.0, 30.0,
                _modes((("Standard", 0x81, 100.0), ("DenseBoost", 0x85, 31.25),
                        ("HQ", 0x83, 31.25), ("UltraDense", 0x86, 31.25)), 30.0),
                typical=1),
    "c1": Model("c1", 460800, "rpm", 8, 0x85, 5000, 10.0, 12.0,
                _modes((("Standard", 0x81, 200.0), ("DenseBoost", 0x85, 200.0)), 12.0),
                typical=1),
}


def model(name: str) -> Model:
    try:
        return MODELS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown scanner model {name!r}; choose one of {', '.join(MODELS)}") from None
