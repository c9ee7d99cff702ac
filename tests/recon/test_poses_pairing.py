"""Capture-order pairing (recon.poses.pairing) on synthetic capture metadata: two train rings of 12
and a held-out test ring of 4, as a turntable rig records them (sequence, frame, loop, time). The
pair list is checked against its closed form: which pairs, how many, and that only the order
decides (renamed or shuffled views give the same pairs)."""
import random

import pytest

from recon.poses import ViewOrder, capture_order_pairs


def rig_order(rings=(("train", 12), ("train", 12), ("test", 4))) -> list[ViewOrder]:
    """Views named as the capture names them (<split>_<index within split>), rings in shooting order."""
    views, per_split, time = [], {}, 0
    for ring, (split, n) in enumerate(rings):
        for k in range(n):
            i = per_split.get(split, 0)
            per_split[split] = i + 1
            views.append(ViewOrder(f"{split}_{i:03d}", f"{split}/{ring}", k, n, True, time))
            time += 1
    return views


def unordered(pairs) -> set[frozenset]:
    return {frozenset(p) for p in pairs}


def test_pairs_follow_the_rings_with_loop_closure_and_link_the_held_out_ring():
    views = rig_order()
    pairs = unordered(capture_order_pairs(views, window=2, link_window=1))
    ring0 = [f"train_{k:03d}" for k in range(12)]
    ring1 = [f"train_{k:03d}" for k in range(12, 24)]
    test = [f"test_{k:03d}" for k in range(4)]
    # within a ring: the next two frames, wrapping round (loop closure), nothing farther
    for ring in (ring0, ring1):
        for k in range(12):
            assert frozenset((ring[k], ring[(k + 1) % 12])) in pairs
            assert frozenset((ring[k], ring[(k + 2) % 12])) in pairs
            assert frozenset((ring[k], ring[(k + 3) % 12])) not in pairs
            assert frozenset((ring[k], ring[(k + 6) % 12])) not in pairs
    assert frozenset(("train_011", "train_000")) in pairs and frozenset(("train_023", "train_012")) in pairs
    # between the train rings: frame k with frames k-1, k, k+1 of the other (same turntable angle)
    for k in range(12):
        for d in (-1, 0, 1):
            assert frozenset((ring0[k], ring1[(k + d) % 12])) in pairs
        assert frozenset((ring0[k], ring1[(k + 4) % 12])) not in pairs
    # across the split: held-out frame k meets train frames 3k-1..3k+1 of both rings (12 / 4 = 3)
    for k in range(4):
        for ring in (ring0, ring1):
            assert {p for p in pairs if test[k] in p and p & set(ring)} == \
                {frozenset((test[k], ring[(3 * k + d) % 12])) for d in (-1, 0, 1)}
    # the 4-ring: steps up to a quarter turn (1 frame), not its opposite views
    assert frozenset((test[0], test[1])) in pairs and frozenset((test[0], test[2])) not in pairs
    # closed form: within 12*2 per train ring, the 4-ring's 4, links 12*3 + 2 * 4*3
    assert len(pairs) == 2 * 24 + 4 + 36 + 24 == 112
    assert len(capture_order_pairs(views, window=2, link_window=1)) == 112  # no duplicates


def test_only_the_shooting_order_decides_not_names_or_list_order():
    views = rig_order()
    rng = random.Random(0)
    alias = {v.name: f"img{rng.randrange(10**9):09d}" for v in views}  # names that sort at random
    renamed = [ViewOrder(alias[v.name], v.sequence, v.frame, v.frames, v.closed, v.time) for v in views]
    rng.shuffle(renamed)
    want = {frozenset(alias[n] for n in p) for p in capture_order_pairs(views, 3, 1)}
    assert unordered(capture_order_pairs(renamed, 3, 1)) == want


def test_open_sequences_do_not_wrap_and_single_views_meet_their_neighbours_in_time():
    views = [ViewOrder(f"g{k}", "train/0", k, 6, False, k) for k in range(6)]
    views.append(ViewOrder("lone", "test/0", 0, 1, False, 6))
    pairs = unordered(capture_order_pairs(views, window=1, link_window=1))
    assert frozenset(("g5", "g0")) not in pairs  # a gantry row is not a loop
    assert {p for p in pairs if "lone" in p} == {frozenset(("lone", g)) for g in ("g3", "g4", "g5")}
    assert len(pairs) == 5 + 3


def test_bad_order_is_refused():
    with pytest.raises(ValueError, match="unique"):
        capture_order_pairs([ViewOrder("a", "s", 0, 2, True, 0), ViewOrder("a", "s", 1, 2, True, 1)])
    with pytest.raises(ValueError, match="twice"):
        capture_order_pairs([ViewOrder("a", "s", 0, 2, True, 0), ViewOrder("b", "s", 0, 2, True, 1)])
    with pytest.raises(ValueError, match="frame 2"):
        ViewOrder("a", "s", 2, 2, True, 0)


def test_doubling_offsets_give_short_and_long_baselines_in_closed_form():
    """Steps 1, 2, 4, 8 within each ring of a 1000-view layout shrunk to rings of 32 + 32 + 32 and
    a held-out 8: each train frame meets the frames 1, 2, 4 and 8 ahead (wrapping: loop closure)
    and nothing between; the rings are linked at the same phase whatever the steps; pairs follow
    ``N_ring * len(offsets)`` per ring; the 8-ring keeps steps up to a quarter turn, 1 and 2 (16
    pairs; step 4 would pair each view with the opposite one)."""
    from recon.poses.pairing import doubling_offsets

    assert doubling_offsets(12) == (1, 2, 4, 8) and doubling_offsets(1) == (1,) and doubling_offsets(16)[-1] == 16
    views = rig_order((("train", 32), ("train", 32), ("train", 32), ("test", 8)))
    pairs = unordered(capture_order_pairs(views, window=12, link_window=1, offsets=doubling_offsets(12)))
    ring = [f"train_{k:03d}" for k in range(32, 64)]
    for k in range(32):
        ahead = {d for d in range(1, 17) if frozenset((ring[k], ring[(k + d) % 32])) in pairs}
        assert ahead == {1, 2, 4, 8}, (k, ahead)
    assert frozenset(("train_063", "train_032")) in pairs  # loop closure
    # ring 0 and ring 2 (not adjacent in shooting order) are linked too: same phase +- 1
    assert {p for p in pairs if "train_010" in p and p & {f"train_{k:03d}" for k in range(64, 96)}} == \
        {frozenset(("train_010", f"train_{74 + d:03d}")) for d in (-1, 0, 1)}
    # held-out frame k meets train frames 4k-1..4k+1 of each ring (32 / 8 = 4)
    assert {p for p in pairs if "test_003" in p and p & set(ring)} == \
        {frozenset(("test_003", ring[12 + d])) for d in (-1, 0, 1)}
    assert frozenset(("test_000", "test_002")) in pairs and frozenset(("test_000", "test_004")) not in pairs
    within = 3 * 32 * 4 + (8 + 8)
    links = 3 * 32 * 3 + 3 * 8 * 3
    assert len(pairs) == within + links == 760
    with pytest.raises(ValueError, match="offsets"):
        capture_order_pairs(views, offsets=(0, 1))
