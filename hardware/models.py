"""What differs between scanner models: baud rate, motor control, rates (protocol note B7, B8)."""

from __future__ import annotations

from dataclasses import dataclass


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


MODELS = {
    "a1": Model("a1", 115200, "dtr", 1, 0x82, 4000, 5.5, 12.0),
    "a2": Model("a2", 115200, "pwm", 2, 0x82, 4000, 10.0, 12.0),
    "a3": Model("a3", 256000, "pwm", 3, 0x82, 10000, 10.0, 25.0),
    "s1": Model("s1", 256000, "rpm", 6, 0x85, 9200, 10.0, 40.0),
    "s2": Model("s2", 1000000, "rpm", 7, 0x85, 32000, 10.0, 30.0),
    "c1": Model("c1", 460800, "rpm", 8, 0x85, 5000, 10.0, 12.0),
}


def model(name: str) -> Model:
    try:
        return MODELS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown scanner model {name!r}; choose one of {', '.join(MODELS)}") from None
