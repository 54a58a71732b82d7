"""MCAP topic names: pinned byte for byte (logs recorded before must replay), derived from bus keys."""

from __future__ import annotations

from cellctl.bus import keys, topics


def test_fixed_topic_names_are_pinned() -> None:
    """Renaming a topic would orphan every recorded log: these strings are the on-disk layout."""
    assert topics.FIXED_TOPICS == (
        "/camera/image",
        "/camera/pose",
        "/bin/identification",
        "/bin/identification_fused",
        "/bin/pose",
        "/tf",
        "/scene",
        "/events",
        "/classifier/heatmap",
        "/wash/plan",
        "/wash/round",
        "/references",
    )
    assert len(set(topics.FIXED_TOPICS)) == len(topics.FIXED_TOPICS)


def test_exchange_topics_derive_from_the_bus_key_and_parse_back() -> None:
    key = keys.robot_op("cell1", "move")
    assert topics.request(key) == "cell/cell1/robot/move/request"
    assert topics.reply(key) == "cell/cell1/robot/move/reply"
    assert topics.exchange_of(topics.request(key)) == (key, "request")
    assert topics.exchange_of(topics.reply(key)) == (key, "reply")
    for t in (*topics.FIXED_TOPICS, keys.cmd("cell1"), keys.status("cell1")):
        assert topics.exchange_of(t) is None, t


def test_no_topic_literal_outside_the_topics_module() -> None:
    """Writers and readers of cycle logs name topics through cellctl.bus.topics only."""
    from cellctl.config import project_root

    root = project_root() / "cellctl"
    quoted = [f'"{t}"' for t in topics.FIXED_TOPICS if t != "/events"]  # "/events" is also an HMI URL
    quoted += ['"/request"', '"/reply"', '}/request"', '}/reply"']
    offenders = []
    for path in sorted(root.rglob("*.py")):
        if path.name == "topics.py" and path.parent.name == "bus":
            continue
        text = path.read_text(encoding="utf-8")
        offenders += [f"{path.relative_to(root)}: {q}" for q in quoted if q in text]
    assert offenders == []
