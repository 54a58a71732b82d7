"""The shared login throttle: back-off per (user, address) and per address, bounded logs and memory."""

from __future__ import annotations

import logging

import pytest

from cellctl.login_throttle import LoginThrottle, ThrottleConfig


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def _attack(th: LoginThrottle, clock: Clock, n: int, user: str = "plc", address: str = "127.0.0.2") -> float:
    """``n`` wrong passwords from one address, each after waiting out the back-off it was charged."""
    charged = 0.0
    for _ in range(n):
        wait = th.retry_after(user, address)
        charged += wait
        clock.t += wait
        assert th.retry_after(user, address) == 0
        th.failed(user, address)
    return charged


def test_1000_guesses_cost_the_attacker_over_60_s_in_at_most_20_log_lines(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    th = LoginThrottle(ThrottleConfig(), "OPC UA", clock)
    with caplog.at_level(logging.INFO, logger="cellctl.login_throttle"):
        charged = _attack(th, clock, 1000)
    lines = [r for r in caplog.records if r.name == "cellctl.login_throttle"]
    print(f"1000 wrong passwords: {charged:.0f} s of back-off charged, {len(lines)} log lines")
    assert charged >= 60 and len(lines) <= 20
    assert th.counters.failures == 1000 and th.counters.lockouts == 2
    # the right user from another address is not slowed at all, nor is another user from another address
    assert th.retry_after("plc", "127.0.0.3") == 0 and th.retry_after("operator", "127.0.0.4") == 0
    # from the attacker's address, even the right password must wait (it is not checked)
    assert th.retry_after("plc", "127.0.0.2") > 0 and th.counters.throttled >= 1


def test_the_owner_at_the_attackers_address_waits_at_most_the_address_cap() -> None:
    """A shared address (NAT, a kiosk): another user there is slowed by the looser address limit only."""
    clock = Clock()
    cfg = ThrottleConfig()
    th = LoginThrottle(cfg, "HMI", clock)
    _attack(th, clock, 200, user="anna")
    assert 0 < th.retry_after("ben", "127.0.0.2") <= cfg.address_max_s
    assert th.retry_after("anna", "127.0.0.2") == pytest.approx(cfg.pair_max_s)
    clock.t += cfg.address_max_s
    assert th.retry_after("ben", "127.0.0.2") == 0
    th.succeeded("ben", "127.0.0.2")  # ben's own login leaves anna's pair and the address as they are
    assert th.retry_after("anna", "127.0.0.2") > 0


def test_back_off_doubles_and_a_try_during_it_does_not_lengthen_it() -> None:
    clock = Clock()
    th = LoginThrottle(ThrottleConfig(pair_free=3, base_s=1.0), "OPC UA", clock)
    waits = [th.failed("plc", "a") for _ in range(3)]
    assert waits == [0.0, 0.0, 1.0]
    assert th.failed("plc", "a") == 2.0 and th.failed("plc", "a") == 4.0
    for _ in range(50):
        assert th.retry_after("plc", "a") == pytest.approx(4.0)
    clock.t += 4.0
    assert th.retry_after("plc", "a") == 0
    th.succeeded("plc", "a")
    assert th.failed("plc", "a") == 0.0  # the pair starts again after a success


def test_memory_is_bounded_under_a_flood_of_names() -> None:
    clock = Clock()
    th = LoginThrottle(ThrottleConfig(max_keys=100, address_free=1000), "HMI", clock)
    for i in range(5000):
        th.failed(f"user{i}", "127.0.0.9")
    assert len(th._keys) <= 100
    assert th.retry_after("someone", "127.0.0.9") > 0  # the address key, refreshed by every failure, stays


def test_forget_must_outlast_the_longest_back_off() -> None:
    with pytest.raises(ValueError, match="forget_s 100 is shorter than the longest back-off 300"):
        ThrottleConfig(forget_s=100)
