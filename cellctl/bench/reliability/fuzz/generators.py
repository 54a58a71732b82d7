"""Seeded hostile payloads for the PLC command key: one generator per category.

:class:`CommandFuzzer` makes :class:`FuzzCase` s from one ``random.Random(seed)``; the same seed
gives the same cases, so a violation found by ``cellctl bench fuzz --seed S`` replays exactly.
"""

from __future__ import annotations

import json
import random
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from cellctl.messages import MESSAGE_TYPES, PackMLCommand
from cellctl.surface import SURFACES

__all__ = ["CATEGORIES", "CATEGORIES_HOSTILE", "REJECT", "CommandFuzzer", "FuzzCase"]

NAMES = [c.name for c in PackMLCommand]
REJECT = "reject"
"""``FuzzCase.expect`` for a payload every state must refuse."""

_CMD = "cellctl/Command"
_FIELDS = ("type", "v", "command", "cntrl_cmd", "request_id", "params")


@dataclass(frozen=True)
class FuzzCase:
    """One payload for the command key.

    Attributes:
        category: which generator made it (see :data:`CATEGORIES`).
        payload: the bytes sent.
        expect: :data:`REJECT`, a PackML command name (a valid command: accepted exactly when
            allowed in the current state), or None (either answer is fine).
        request_id: the ``request_id`` a decoded Ack must carry back (valid commands only).
    """

    category: str
    payload: bytes
    expect: str | None = REJECT
    request_id: str | None = None


def _dump(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":")).encode()


class CommandFuzzer:
    """Hostile command payloads from one seeded ``random.Random`` (no hypothesis needed).

    Args:
        seed: the seed; the same seed gives the same cases.
        max_bytes: the daemon's ``supervisor.max_command_bytes`` (oversize cases straddle it).
    """

    def __init__(self, seed: int, max_bytes: int = 64 * 1024) -> None:
        self.seed = seed
        self.rng = random.Random(seed)
        self.max_bytes = max_bytes
        self._n = 0
        self._gens: dict[str, Callable[[], FuzzCase]] = {
            name[len("_c_") :]: getattr(self, name) for name in sorted(dir(self)) if name.startswith("_c_")
        }

    # --- building blocks ------------------------------------------------------------------

    def _text(self, n: int | None = None) -> str:
        """Random text with control characters, non-BMP, bidi overrides and lone surrogates."""
        r = self.rng
        n = r.choice([0, 1, 5, 20, 127, 128, 129, 1000]) if n is None else n
        pools = ["abcXYZ019 -_/.", '\x00\x01\x1b\x7f\n\t"\\', "éß中文😀\u202e\ufeff", "\ud800\udfff"]
        weights = [8, 2, 2, 1]
        return "".join(r.choice(r.choices(pools, weights)[0]) for _ in range(n))

    def _value(self, depth: int = 0) -> Any:
        """Any JSON-able value (NaN and Infinity included, as Python's json writes them)."""
        r = self.rng
        kind = r.choice(["null", "bool", "int", "bigint", "float", "special", "str", "list", "dict"])
        if kind == "null":
            return None
        if kind == "bool":
            return r.random() < 0.5
        if kind == "int":
            return r.randint(-20, 20)
        if kind == "bigint":
            return r.choice([2**31, 2**63, -(2**63) - 1, 10**30, -(10**100)])
        if kind == "float":
            return r.choice([0.5, -1.5, 1e-300, 1e300, 2.0])
        if kind == "special":
            return r.choice([float("nan"), float("inf"), float("-inf")])
        if kind == "str":
            return self._text()
        if depth > 2:
            return []
        if kind == "list":
            return [self._value(depth + 1) for _ in range(r.randint(0, 4))]
        return {self._text(r.randint(0, 8)): self._value(depth + 1) for _ in range(r.randint(0, 4))}

    def _rid(self) -> str:
        self._n += 1
        return f"fz-{self.seed}-{self._n}"

    def _valid(self, name: str | None = None, rid: bool = True, start_params: bool = True) -> dict[str, Any]:
        """A valid Command object (``name`` or a random one, by name or by code)."""
        r = self.rng
        name = name or r.choice(NAMES)
        obj: dict[str, Any] = {"type": _CMD, "v": 1}
        if r.random() < 0.5:
            obj["command"] = name
        else:
            obj["cntrl_cmd"] = PackMLCommand[name].value
        if rid:
            obj["request_id"] = self._rid()
        if name == "start" and start_params and r.random() < 0.3:
            obj["params"] = r.choice(
                [
                    {"mode": "evaluate"},
                    {"surface": r.choice(list(SURFACES))},
                    {"mode": "collect", "label": r.choice(["clean", "dirty"]), "perturb_m": 0.01, "seed": 7},
                ]
            )
        if r.random() < 0.5:  # key order is no part of the contract
            items = list(obj.items())
            r.shuffle(items)
            obj = dict(items)
        return obj

    def _expect_valid(self, category: str, obj: dict[str, Any], payload: bytes | None = None) -> FuzzCase:
        name = obj.get("command") or PackMLCommand(obj["cntrl_cmd"]).name
        return FuzzCase(category, payload if payload is not None else _dump(obj), name, obj.get("request_id"))

    # --- generators: one per category -------------------------------------------------------

    def _c_empty(self) -> FuzzCase:
        return FuzzCase("empty", self.rng.choice([b"", b" ", b"\n\t\r", b"null", b"{}", b"\x00"]))

    def _c_random_bytes(self) -> FuzzCase:
        return FuzzCase("random_bytes", self.rng.randbytes(self.rng.choice([1, 2, 8, 64, 512, 4096])))

    def _c_invalid_utf8(self) -> FuzzCase:
        r = self.rng
        good = _dump(self._valid())
        bad = r.choice([b"\xff", b"\xfe\xff", b"\xc3\x28", b"\xed\xa0\x80", b"\xc0\xaf", b"\xf4\x90\x80\x80", b"\x80"])
        at = r.randrange(len(good) + 1)
        return FuzzCase("invalid_utf8", good[:at] + bad + good[at:])

    def _c_truncated_json(self) -> FuzzCase:
        good = _dump(self._valid())
        return FuzzCase("truncated_json", good[: self.rng.randrange(1, len(good))])

    def _c_nesting_bomb(self) -> FuzzCase:
        r = self.rng
        d = r.choice([33, 100, 990, 1000, 5000, 30000])
        kind = r.choice(["open_arrays", "closed_arrays", "objects", "in_params"])
        if kind == "open_arrays":
            payload = b"[" * d
        elif kind == "closed_arrays":
            payload = b"[" * d + b"]" * d
        elif kind == "objects":
            payload = b'{"a":' * d + b"1" + b"}" * d
        else:
            head = _dump({"type": _CMD, "v": 1, "command": "start"})[:-1]
            payload = head + b',"params":{"mode":' + b"[" * d + b"]" * d + b"}}"
        return FuzzCase("nesting_bomb", payload[: self.max_bytes + 16])

    def _c_oversize(self) -> FuzzCase:
        r = self.rng
        obj = self._valid(start_params=False)
        good = _dump(obj)
        if r.random() < 0.3:
            # exactly at the limit: still a command (whitespace is valid JSON)
            return self._expect_valid("oversize", obj, good + b" " * (self.max_bytes - len(good)))
        extra = r.choice([1, 100, 10_000, 1_000_000])
        if r.random() < 0.5:
            return FuzzCase("oversize", good + b" " * (self.max_bytes - len(good) + extra))
        obj["request_id"] = "x" * (self.max_bytes + extra)
        return FuzzCase("oversize", _dump(obj))

    def _c_huge_strings(self) -> FuzzCase:
        r = self.rng
        obj = self._valid()
        target = r.choice(["request_id", "command", "type", "param"])
        big = "y" * r.choice([129, 4096, self.max_bytes // 2])
        if target == "param":
            obj = {"type": _CMD, "v": 1, "command": "start", "params": {"dataset": big, "mode": big}}
        else:
            obj[target] = big
        return FuzzCase("huge_strings", _dump(obj))

    def _c_hostile_request_id(self) -> FuzzCase:
        obj = self._valid(start_params=False)
        rid = self._text(self.rng.choice([1, 10, 64, 128]))
        obj["request_id"] = rid
        payload = json.dumps(obj, ensure_ascii=self.rng.random() < 0.5).encode("utf-8", "surrogatepass")
        if any("\ud800" <= c <= "\udfff" for c in rid):
            return FuzzCase("hostile_request_id", payload)  # lone surrogates are not text
        return self._expect_valid("hostile_request_id", obj, payload)

    def _c_not_an_object(self) -> FuzzCase:
        v = self._value()
        while isinstance(v, dict):
            v = self._value()
        return FuzzCase("not_an_object", json.dumps(v).encode())

    def _c_wrong_field_type(self) -> FuzzCase:
        r = self.rng
        wrong = {
            "type": [1, None, [], {}, True, "cellctl/command", " cellctl/Command"],
            "v": ["1", [], {}, None, 1.5, [1]],
            "command": [1, [], {}, True, "RESET", "reset ", "", "jump", "start\x00"],
            "cntrl_cmd": ["1", True, False, [], {}, 1.5, "reset"],
            "request_id": [1, [], {}, True, 1.5, {"id": "x"}],
            "params": [[], "x", 1, True, None, [["mode", "collect"]]],
        }
        obj = self._valid(start_params=False)
        f = r.choice(_FIELDS)
        if f == "cntrl_cmd":
            obj.pop("command", None)
        if f == "command":
            obj.pop("cntrl_cmd", None)
        obj[f] = r.choice(wrong[f])
        return FuzzCase("wrong_field_type", _dump(obj))

    def _c_unknown_fields(self) -> FuzzCase:
        r = self.rng
        obj = self._valid()
        for _ in range(r.randint(1, 4)):
            k = r.choice(["Command", "cmd", "TYPE", "state", "__proto__", "constructor", "param", self._text(6)])
            if k not in _FIELDS:
                obj[k] = self._value()
        if set(obj) <= set(_FIELDS):
            obj["extra"] = 1
        return FuzzCase("unknown_fields", _dump(obj))

    def _c_wrong_type_or_version(self) -> FuzzCase:
        r = self.rng
        obj = self._valid()
        if r.random() < 0.5:
            others = sorted(t for t in MESSAGE_TYPES if t != _CMD)
            obj["type"] = r.choice([*others, "cellctl/Cmd", "Command", "", "cellctl/Command/v1"])
        else:
            obj["v"] = r.choice([0, 2, -1, 2**64, "1", 1.5, None, True, [1]])
        return FuzzCase("wrong_type_or_version", _dump(obj))

    def _c_bad_cntrl_cmd(self) -> FuzzCase:
        r = self.rng
        raw = r.choice(
            [b"0", b"11", b"-1", b"2147483648", b"9223372036854775808", b"1e400", b"1.5", b"2.000001"]
            + [b"true", b"false", b'"2"', b'"reset"', b"NaN", b"Infinity", b"-Infinity", b"null", b"[2]"]
            + [b"1" * 5000, b"-" + b"9" * 4301]
        )
        rid = f',"request_id":"{self._rid()}"' if r.random() < 0.5 else ""
        return FuzzCase("bad_cntrl_cmd", b'{"type":"cellctl/Command","v":1,"cntrl_cmd":' + raw + rid.encode() + b"}")

    def _c_command_and_code(self) -> FuzzCase:
        r = self.rng
        name = r.choice(NAMES)
        obj: dict[str, Any] = {"type": _CMD, "v": 1}
        if r.random() < 0.7:  # both, even when they agree
            obj["command"] = name
            obj["cntrl_cmd"] = PackMLCommand[r.choice([name, *NAMES])].value
        else:  # neither
            obj["request_id"] = self._rid()
        return FuzzCase("command_and_code", _dump(obj))

    def _c_nan_infinity(self) -> FuzzCase:
        r = self.rng
        obj = self._valid()
        special = r.choice([float("nan"), float("inf"), float("-inf")])
        where = r.choice(["v", "cntrl_cmd", "request_id", "command", "type", "param"])
        if where == "param":
            obj.pop("command", None)
            obj.update(cntrl_cmd=2, params={r.choice(["perturb_m", "seed", "mode", "nan"]): special})
        else:
            if where == "cntrl_cmd":
                obj.pop("command", None)
            obj[where] = special
        return FuzzCase("nan_infinity", json.dumps(obj).encode())

    def _c_hostile_start_params(self) -> FuzzCase:
        r = self.rng
        bad: list[dict[str, Any]] = [
            {"speed": 3},
            {"mode": "evaluate", "__class__": {}},
            {"mode": "debug"},
            {"mode": ["collect"]},
            {"mode": {"collect": True}},
            {"mode": "collect"},
            {"mode": "collect", "label": "grimy"},
            {"mode": "collect", "label": ["dirty"]},
            {"surface": "top"},
            {"surface": None},
            {"perturb_m": -0.01},
            {"perturb_m": 0.5},
            {"perturb_m": 1e308},
            {"perturb_m": "0.01"},
            {"perturb_m": True},
            {"perturb_m": [0.01]},
            {"seed": -1},
            {"seed": 1.5},
            {"seed": True},
            {"seed": "7"},
            {"seed": 2**63},
            {"seed": 10**200},
            {"dataset": {"path": "/tmp"}},
            {"dataset": 42},
            {"dataset": ""},
            {"dataset": ["a", "b"]},
            {self._text(5): self._value()},
        ]
        params = dict(r.choice(bad))
        if r.random() < 0.3:  # a valid-looking key alongside
            params.setdefault("surface", "external")
        obj = {"type": _CMD, "v": 1, "request_id": self._rid(), "params": params}
        obj.update({"command": "start"} if r.random() < 0.5 else {"cntrl_cmd": 2})
        return FuzzCase("hostile_start_params", json.dumps(obj).encode())

    def _c_params_on_other_commands(self) -> FuzzCase:
        r = self.rng
        obj = self._valid(r.choice([n for n in NAMES if n != "start"]))
        obj["params"] = r.choice([{"mode": "evaluate"}, {"force": True}, {"x": self._value()}])
        return FuzzCase("params_on_other_commands", json.dumps(obj).encode())

    def _c_duplicate_keys(self) -> FuzzCase:
        r = self.rng
        a, b = r.choice(NAMES), r.choice(NAMES)
        dup = r.choice(
            [
                f'"command":"{a}","command":"{b}"',
                f'"command":"{a}","cntrl_cmd":null,"cntrl_cmd":{PackMLCommand[b].value}',
                f'"type":"cellctl/Status","type":"{_CMD}","command":"{a}"',
                f'"v":2,"v":1,"command":"{a}"',
                f'"command":"{a}","params":{{"seed":1,"seed":-1}}',
            ]
        )
        head = '"type":"cellctl/Command","v":1,' if '"type"' not in dup else ""
        return FuzzCase("duplicate_keys", ("{" + head + dup + "}").encode())

    def _c_bom_and_encodings(self) -> FuzzCase:
        r = self.rng
        text = json.dumps(self._valid())
        payload = r.choice(
            [
                b"\xef\xbb\xbf" + text.encode(),
                text.encode("utf-16"),
                text.encode("utf-16-le"),
                text.encode("utf-32"),
                text.encode("utf-16-be"),
            ]
        )
        return FuzzCase("bom_and_encodings", payload)

    def _c_valid(self) -> FuzzCase:
        r = self.rng
        obj = self._valid(rid=r.random() < 0.8)
        text = json.dumps(obj, separators=r.choice([(",", ":"), (", ", ": ")]), indent=r.choice([None, 2]))
        return self._expect_valid("valid", obj, (r.choice(["", " ", "\n"]) + text + r.choice(["", "\n"])).encode())

    # --- the stream ---------------------------------------------------------------------------

    def next_case(self) -> FuzzCase:
        """One case; valid commands are about a sixth of the stream so the machine keeps moving."""
        r = self.rng
        if r.random() < 0.15:
            return self._c_valid()
        return self._gens[r.choice(CATEGORIES_HOSTILE)]()

    def cases(self, n: int) -> Iterator[FuzzCase]:
        for _ in range(n):
            yield self.next_case()


CATEGORIES_HOSTILE = tuple(
    sorted(n[len("_c_") :] for n in dir(CommandFuzzer) if n.startswith("_c_") and n != "_c_valid")
)
CATEGORIES = (*CATEGORIES_HOSTILE, "valid")
"""Every category a case can come from."""
