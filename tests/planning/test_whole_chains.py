"""Chain viewpoints a tour takes back when it has moves the arm may refuse (``_readd_chains``)."""

from __future__ import annotations

import numpy as np

from cellctl.planning.whole.chains import _readd_chains

# chains home: 5 -> 4 -> 3 -> home, 7 -> 6 -> home, 2 -> home
PARENT = np.array([-1, -1, -1, -1, 3, 4, -1, 6], dtype=np.int64)


def _fake_tour(bad_unless: dict[int, set[int]], calls: list[list[int]]):
    """A tour whose unverified moves are the stuck viewpoints whose chain is not all visited."""

    def tour(ids: np.ndarray) -> tuple:
        have = set(ids.tolist())
        calls.append(sorted(have))
        unverified = sum(1 for k, chain in bad_unless.items() if k in have and not chain <= have)
        secs = [1.0] * len(have)
        return ("order", "D", "paths", secs, 0, unverified, np.zeros(0, np.int64))

    return tour


def test_only_the_stuck_viewpoints_chains_come_back_when_they_suffice():
    sel = np.array([2, 5, 7])
    calls: list[list[int]] = []
    tour = _fake_tour({5: {3, 4}}, calls)
    first = tour(sel)
    got_sel, got = _readd_chains(sel, np.array([5]), PARENT, first, tour)
    assert got_sel.tolist() == [2, 3, 4, 5, 7]  # 7's chain (6) is not taken: 7 was not stuck
    assert got[5] == 0 and len(got) == 6
    assert calls[1:] == [[2, 3, 4, 5, 7]]  # every chain was never tried


def test_every_chain_comes_back_when_the_stuck_ones_do_not_suffice():
    sel = np.array([2, 5, 7])
    calls: list[list[int]] = []
    # 7 needs its chain too, but the tour only named 5 as stuck
    tour = _fake_tour({5: {3, 4}, 7: {6}}, calls)
    first = tour(sel)
    got_sel, got = _readd_chains(sel, np.array([5]), PARENT, first, tour)
    assert got_sel.tolist() == [2, 3, 4, 5, 6, 7]
    assert got[5] == 0


def test_the_first_tour_is_kept_when_no_chain_helps():
    sel = np.array([2, 5])
    calls: list[list[int]] = []
    tour = _fake_tour({2: {99}}, calls)  # 2's trouble no chain fixes
    first = tour(sel)
    got_sel, got = _readd_chains(sel, np.array([2]), PARENT, first, tour)
    assert got_sel.tolist() == [2, 5] and got[5] == first[5] == 1
