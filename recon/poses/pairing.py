"""Which image pairs structure from motion matches: the capture's shooting order, not all pairs.

A rig (or a hand-held sweep) shoots each sequence in order, as a video's frames: a turntable
ring is one revolution, its last frame next to its first. The pairs are

* **within a sequence**: each frame with the frames ``offsets`` ahead of it: the next ``window``
  frames (``1 .. window``, a sequential matcher's overlap), or doubling steps ``1, 2, 4, ..`` up
  to ``window`` (:func:`doubling_offsets`: a few short baselines for matching, a few long ones for
  triangulation, ``log2(window) + 1`` pairs per frame instead of ``window``), wrapping round a
  closed sequence (loop closure: frame n-1 meets frames 0, 1, ...); on a closed sequence no step
  exceeds a quarter of it (:data:`MAX_RING_FRACTION`: on a ring of 8, step 4 pairs each view with
  the opposite one, and the global mapper folded the small test capture on such pairs);
* **between sequences**: every two sequences are linked at the same phase of their sweep. Frame
  ``a`` of the shorter sequence (``n_s`` frames) meets frames ``round(a n_l / n_s) +- link_window``
  of the longer one (``n_l``): on a turntable, the views shot at the same turntable angle from
  the other ring. Single views (``frames == 1``) meet the ``2 link_window + 1`` nearest frames by
  capture time in every sequence instead.

Pairs grow as ``N (len(offsets) + (S - 1)(2 link_window + 1))`` for N views in S sequences: linear in
N, where exhaustive matching is ``N (N - 1) / 2``. Only the shooting order enters (sequence, frame
index, frame count, closed, capture time): no pose, no file name.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["ViewOrder", "capture_order_pairs", "doubling_offsets", "write_pair_list"]


@dataclass(frozen=True)
class ViewOrder:
    """One view's place in the shooting order.

    name: the view's name (image stem). sequence: id of the sweep it belongs to. frame: index
    within the sweep (0 .. frames-1, shooting order). frames: the sweep's length. closed: the
    sweep returns to its start (a ring). time: the view's index in the whole capture.
    """

    name: str
    sequence: str
    frame: int
    frames: int
    closed: bool
    time: int

    def __post_init__(self) -> None:
        if not 0 <= self.frame < self.frames:
            raise ValueError(f"view {self.name!r}: frame {self.frame} outside 0..{self.frames - 1}")


#: the longest step within a closed sequence, as a fraction of its frames (a quarter turn)
MAX_RING_FRACTION = 0.25


def doubling_offsets(window: int) -> tuple[int, ...]:
    """``(1, 2, 4, ..)``: the powers of two up to ``window`` (>= 1); 12 -> (1, 2, 4, 8)."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    return tuple(1 << k for k in range(window.bit_length()))


def _within(members: list[ViewOrder], offsets: Sequence[int]) -> set[tuple[str, str]]:
    """Each frame with the frames ``offsets`` ahead, wrapping when the sequence is closed (steps
    beyond MAX_RING_FRACTION of it dropped, the first step always kept)."""
    n = len(members)
    if members[0].closed:
        longest = max(int(MAX_RING_FRACTION * members[0].frames), min(offsets))
        offsets = [step for step in offsets if step <= longest]
    pairs = set()
    for i in range(n):
        for step in offsets:
            j = i + step
            if j >= n:
                if not members[0].closed:
                    break
                j %= n
            if j != i:
                pairs.add((members[i].name, members[j].name))
    return pairs


def _between(a: list[ViewOrder], b: list[ViewOrder], link_window: int) -> set[tuple[str, str]]:
    """Frames of the shorter sequence with the same-phase frames (+- link_window) of the longer."""
    short, long_ = (a, b) if len(a) <= len(b) else (b, a)
    n_s, n_l = len(short), len(long_)
    closed = long_[0].closed
    pairs = set()
    for k, view in enumerate(short):
        centre = round(k * n_l / n_s)
        for j in range(centre - link_window, centre + link_window + 1):
            if closed:
                j %= n_l
            elif not 0 <= j < n_l:
                continue
            pairs.add((view.name, long_[j].name))
    return pairs


def _near_in_time(view: ViewOrder, members: list[ViewOrder], count: int) -> set[tuple[str, str]]:
    nearest = sorted(members, key=lambda m: (abs(m.time - view.time), m.time))[:count]
    return {(view.name, m.name) for m in nearest}


def capture_order_pairs(views: Sequence[ViewOrder], window: int = 8, link_window: int = 1,
                        offsets: Sequence[int] | None = None) -> list[tuple[str, str]]:
    """The image pairs to match, from the shooting order (module docstring).

    views: every view to pose, any order (names unique). window: frames matched ahead within a
    sequence (>= 1). link_window: half-width of the same-phase link between sequences (>= 0).
    offsets: the frame steps matched within a sequence (each >= 1), instead of ``1 .. window``
    (e.g. :func:`doubling_offsets`).
    Returns unique unordered pairs, each ``(first, second)`` in the order of ``views``, sorted by
    that order: deterministic for a given input.
    """
    if window < 1 or link_window < 0:
        raise ValueError(f"window must be >= 1 and link_window >= 0, got {window}, {link_window}")
    steps = tuple(range(1, window + 1)) if offsets is None else tuple(offsets)
    if not steps or min(steps) < 1:
        raise ValueError(f"offsets must be >= 1, got {steps}")
    names = [v.name for v in views]
    if len(set(names)) != len(names):
        raise ValueError("view names must be unique")
    sequences: dict[str, list[ViewOrder]] = {}
    for v in views:
        sequences.setdefault(v.sequence, []).append(v)
    for seq, members in sequences.items():
        members.sort(key=lambda m: m.frame)
        frames = [m.frame for m in members]
        if len(set(frames)) != len(frames):
            raise ValueError(f"sequence {seq!r}: frame index used twice")
    # views of a sequence may be missing (e.g. not given to the estimator): index by position
    pairs: set[tuple[str, str]] = set()
    multi = [m for m in sequences.values() if len(m) > 1]
    singles = [m[0] for m in sequences.values() if len(m) == 1]
    for members in multi:
        pairs |= _within(members, steps)
    for i, a in enumerate(multi):
        for b in multi[i + 1:]:
            pairs |= _between(a, b, link_window)
    for s in singles:
        for members in multi:
            pairs |= _near_in_time(s, members, 2 * link_window + 1)
        for t in singles:  # single views meet each other too: few, and nothing else orders them
            if t.name != s.name:
                pairs.add((s.name, t.name))
    position = {n: i for i, n in enumerate(names)}
    ordered = {tuple(sorted(p, key=position.__getitem__)) for p in pairs if p[0] != p[1]}
    return sorted(ordered, key=lambda p: (position[p[0]], position[p[1]]))


def write_pair_list(path, pairs: Sequence[tuple[str, str]], suffix: str = ".png") -> None:
    """COLMAP's match list (``pycolmap.ImportedPairingOptions.match_list_path``): one
    ``image_name1 image_name2`` line per pair, names as imported (stem + ``suffix``)."""
    with open(path, "w") as f:
        f.writelines(f"{a}{suffix} {b}{suffix}\n" for a, b in pairs)
