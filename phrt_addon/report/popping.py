"""Popping: what an element's switch between raster and ray tracing looks like.

The paper asks that "no element repeatedly changed from raster to ray
tracing" and never measures what a change costs the eye.  For every element
whose selected state flipped between two consecutive frames of a run, this
module takes the pixels the element covers in either frame (the run's ``PHRT
Element`` pass) and measures

    popping = mean LDR-FLIP(run frame f-1, run frame f) over those pixels
            - mean LDR-FLIP(reference frame f-1, reference frame f) over the same pixels,

i.e. how much more those pixels change from one frame to the next than they
change in the reference (which moves with the camera too, but never switches).
Near 0: the switch is invisible beyond the motion; large: a visible pop.  Under the
``BENEFIT`` selection an element traced in both frames also pops when what is traced of it
changes (its effects, or with quality tiers its rate): such pops have ``kind`` ``items`` and
count in the total like a switch between raster and traced (``kind`` ``state``), and are
also reported on their own (``per_100_frames("items")``).  An
element entering or leaving the view also flips, and then pops as much as the
reference changes: about 0.

FLIP is evaluated on the bounding box of the pixels (plus a margin for FLIP's
filters), not the whole frame.  Per run: :class:`PoppingResult` with one
:class:`Pop` per flip, per element sums and the sum per 100 frames.  Runs
without the element pass (rendered before it existed) or without images get
no popping.  Plain numpy, no ``bpy``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import metrics
from ..runs import run_files
from ..schema import ELEMENT_PASS

# Pixels around an element's bounding box given to FLIP (its filters reach a few pixels).
MARGIN_PX = 8


@dataclass
class Pop:
    frame: int          # the frame after the switch
    element: str
    selected: bool      # the element's state after the switch
    pixels: int
    run_flip: float
    reference_flip: float
    kind: str = "state"  # "state": raster <-> traced; "items": the traced effects or rate changed

    @property
    def popping(self) -> float:
        return self.run_flip - self.reference_flip


@dataclass
class PoppingResult:
    frame_count: int
    pops: list = field(default_factory=list)
    note: str = ""

    @property
    def measured(self) -> bool:
        return not self.note

    def per_element(self) -> dict:
        """{element: (flips, summed popping)} of the elements that flipped."""
        table = {}
        for pop in self.pops:
            flips, total = table.get(pop.element, (0, 0.0))
            table[pop.element] = (flips + 1, total + pop.popping)
        return table

    def per_100_frames(self, kind: str | None = None) -> float | None:
        """Summed popping of all flips (of one ``kind`` if given) per 100 frames of the run."""
        if not self.measured or self.frame_count == 0:
            return None
        return 100.0 * sum(pop.popping for pop in self.pops if kind in (None, pop.kind)) / self.frame_count

    def flips_per_100_frames(self) -> float | None:
        if self.frame_count == 0:
            return None
        return 100.0 * len(self.pops) / self.frame_count


class _Frames:
    """Images of a run, read once."""

    def __init__(self, run_dir, elements=False):
        self.run_dir, self.elements, self.cache = Path(run_dir), elements, {}

    def get(self, frame):
        if frame not in self.cache:
            path = run_files.frame_image_path(self.run_dir, frame)
            if path is None:
                self.cache[frame] = None
            elif self.elements:
                passes = metrics.read_passes(path, (metrics.COMBINED_PASS, ELEMENT_PASS))
                self.cache[frame] = (passes[metrics.COMBINED_PASS][..., :3], passes[ELEMENT_PASS][..., 0])
            else:
                self.cache[frame] = (metrics.read_image(path), None)
            if len(self.cache) > 4:  # consecutive pairs only need the last two frames
                self.cache.pop(next(iter(self.cache)))
        return self.cache[frame]


def _crop(mask):
    rows = np.flatnonzero(mask.any(axis=1))
    columns = np.flatnonzero(mask.any(axis=0))
    height, width = mask.shape
    return (slice(max(rows[0] - MARGIN_PX, 0), min(rows[-1] + MARGIN_PX + 1, height)),
            slice(max(columns[0] - MARGIN_PX, 0), min(columns[-1] + MARGIN_PX + 1, width)))


def measure_popping(run_dir, reference_dir, selection_rows=None, reference_maps=None) -> PoppingResult:
    """Popping of every flip of the run in ``run_dir`` against the run in ``reference_dir``.

    ``reference_maps``: a dict shared by the runs of one reference, caching the reference's
    FLIP maps by (frames, window) (an element covers the same pixels in every run)."""
    reference_maps = {} if reference_maps is None else reference_maps
    rows = run_files.read_selection(run_dir) if selection_rows is None else selection_rows
    by_frame = {}
    traced_as = {}  # (frame, element) -> (effects, rate) where the row says (BENEFIT)
    for row in rows:
        by_frame.setdefault(int(row["frame"]), []).append((str(row["element"]), bool(row["selected"])))
        if row.get("effects") is not None or row.get("rate") is not None:
            traced_as[(int(row["frame"]), str(row["element"]))] = (str(row.get("effects") or ""), row.get("rate"))
    frames = sorted(set(by_frame) | {int(row["frame"]) for row in run_files.read_frames(run_dir)})
    result = PoppingResult(frame_count=len(frames))
    first = run_files.frame_image_path(run_dir, frames[0]) if frames else None
    if first is None or first.suffix.lower() != ".exr":
        result.note = "no EXR frame images: popping not measured"
        return result
    try:
        metrics.read_pass(first, ELEMENT_PASS)
    except ValueError:
        result.note = f"no '{ELEMENT_PASS}' pass in the frames: popping not measured"
        return result
    run_frames, reference_frames = _Frames(run_dir, elements=True), _Frames(reference_dir)
    for before, after in zip(frames, frames[1:]):
        state_before = dict(by_frame.get(before, ()))
        state_after = dict(by_frame.get(after, ()))
        flipped = sorted(name for name in set(state_before) | set(state_after)
                         if state_before.get(name, False) != state_after.get(name, False))
        changed = sorted(name for name in set(state_before) & set(state_after)
                         if state_before[name] and state_after[name]
                         and traced_as.get((before, name)) != traced_as.get((after, name)))
        kinds = {**{name: "state" for name in flipped}, **{name: "items" for name in changed}}
        flipped = sorted(kinds)
        if not flipped:
            continue
        pair = run_frames.get(before), run_frames.get(after)
        reference_pair = reference_frames.get(before), reference_frames.get(after)
        if None in pair or None in reference_pair:
            continue
        index_before = {name: position + 1 for position, (name, _) in enumerate(by_frame.get(before, ()))}
        index_after = {name: position + 1 for position, (name, _) in enumerate(by_frame.get(after, ()))}
        for name in flipped:
            mask = np.zeros(pair[0][1].shape, bool)
            if name in index_before:
                mask |= pair[0][1] == index_before[name]
            if name in index_after:
                mask |= pair[1][1] == index_after[name]
            pixels = int(mask.sum())
            if pixels == 0:
                result.pops.append(Pop(after, name, state_after.get(name, False), 0, 0.0, 0.0, kinds[name]))
                continue
            window = _crop(mask)
            inside = mask[window]
            run_map = metrics.flip_map(pair[0][0][window], pair[1][0][window])
            key = (str(reference_dir), before, after, window[0].start, window[0].stop, window[1].start,
                   window[1].stop)
            if key not in reference_maps:
                reference_maps[key] = metrics.flip_map(reference_pair[0][0][window], reference_pair[1][0][window])
            reference_map = reference_maps[key]
            result.pops.append(Pop(after, name, state_after.get(name, False), pixels,
                                   float(run_map[inside].mean()), float(reference_map[inside].mean()), kinds[name]))
    return result
