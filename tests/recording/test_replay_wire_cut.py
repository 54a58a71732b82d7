"""`replay --verify` reads the replayed CycleResult off the bus, where a large one comes cut to the wire's size:
the recorded result is compared as it would have been sent, not as the MCAP keeps it (every view)."""

from __future__ import annotations

from cellctl.bus.codec import decode_as
from cellctl.messages import CycleResult, ViewpointResult
from cellctl.recording.replay import recorded_as_sent
from cellctl.supervisor.publisher import fit_to_wire


def _result(n: int) -> CycleResult:
    views = [ViewpointResult(index=i, label="clean", p_dirty=0.01, heatmap="x" * 600) for i in range(n)]
    return CycleResult(cycle_id="c1", outcome="completed", verdict="clean", viewpoints=views)


def test_a_whole_recorded_result_is_cut_like_the_replayed_one_from_the_bus() -> None:
    recorded = _result(150)  # past 64 KiB with its heat maps
    replayed = decode_as(CycleResult, fit_to_wire(recorded))
    assert replayed.viewpoints_omitted == 150 and recorded != replayed
    assert recorded_as_sent(recorded, replayed) == replayed


def test_a_result_that_fits_is_compared_whole() -> None:
    recorded = _result(3)
    assert recorded_as_sent(recorded, recorded) is recorded
    # a replay whose result was cut where the recording's fits whole: the recording stays whole, so the
    # comparison reports the difference instead of cutting it away
    cut = decode_as(CycleResult, fit_to_wire(_result(150)))
    assert recorded_as_sent(recorded, cut) == recorded != cut
