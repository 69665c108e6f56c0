"""How far the BENEFIT selection's material priors are from what a scene's traced items measure.

The priors (``item_benefit.priors``) guess an item's difference per pixel from its materials,
the same guess in every scene.  What tracing changes differs by scene far more than by material:
measured against the prior, per changed pixel (every item traced, 60 frames of each training path
at a 400 ms budget, median of measured / prior; ``docs/selection.md``):

=============  ==========  ============  ==========
path           shadows     reflections   refractions
=============  ==========  ============  ==========
arcade path1   0.0026      0.45          0.59
arcade path2   0.0014      0.41          0.64
atrium path1   0.28        (0: charged   0.77
                           to the pool's
                           refraction)
=============  ==========  ============  ==========

A shadow's prior is per pixel of its *footprint* on receivers, most of which the caster does not
darken: on arcade the point lights' regions cover most of the frame (a sphere's: 62,848 of 76,800
pixels) while the traced shadow changes a few hundred.  An item never traced, or one whose
estimate decays towards its prior while it is not traced, was valued by that guess: arcade's
shadows 40-140x too high against the LDR-FLIP their tracing removes.

Two corrections of the priors, both per effect:

- ``FITTED``: the geometric mean of the training paths' medians (above), applied from the first
  frame (the judged paths are not in it);
- a scale learned in the replay: the median of measured / prior over the last ``WINDOW``
  measurements of the effect's items (full rate, prior > 0), from ``MIN_SAMPLES`` on, within
  ``RANGE`` of the fitted prior.

And one of the value: a unit of measured change removes more LDR-FLIP as a shadow than as a
reflection, and less as a refraction (``EFFECT_WEIGHT``, fitted on the same paths), so the
selection weights each item's value by its effect's.

Plain numpy, no ``bpy``.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from ..finite import finite
from ..schema import EFFECTS

# In EFFECTS order (shadows, reflections, refractions): (0.0026 * 0.0014 * 0.28) ** (1/3),
# (0.45 * 0.41) ** (1/2), (0.59 * 0.64 * 0.77) ** (1/3).
FITTED = np.array([0.01, 0.43, 0.66])
# LDR-FLIP removed per unit of measured change, relative to reflections (EFFECTS order): each item
# traced alone on 8 frames of each training path, median of its LDR-FLIP drop over its summed
# luminance change; shadows 61, 96, 60, reflections 37, 44, 36, refractions 31, 46, 9 (x1e-6; arcade
# path1, path2, atrium path1): geometric means 70, 39, 23.  Display-referred (sRGB) changes keep the
# same order (shadows 78-107, reflections 50-54, refractions 13-62): no reason to measure in sRGB.
EFFECT_WEIGHT = np.array([1.8, 1.0, 0.6])
WINDOW = 32
MIN_SAMPLES = 3
RANGE = (0.01, 100.0)


class PriorScale:
    """Per effect: the factor the material priors are multiplied by (fitted x learned), and the
    weight of a unit of change in the value (``EFFECT_WEIGHT``)."""

    def __init__(self, fitted=FITTED, learn: bool = True, weight=EFFECT_WEIGHT):
        self.fitted = np.array(fitted, np.float64).reshape(len(EFFECTS))  # copies: the module's stay
        self.weight = np.array(weight, np.float64).reshape(len(EFFECTS))  # each effect's value per change
        self.learn = bool(learn)
        self.ratios = [deque(maxlen=WINDOW) for _ in EFFECTS]
        self.learned = np.ones(len(EFFECTS))

    @property
    def scale(self) -> np.ndarray:
        """(3,) the factor per effect."""
        return self.fitted * self.learned

    def apply(self, priors) -> np.ndarray:
        """(n, 3) the priors scaled."""
        return np.asarray(priors, np.float64).reshape(-1, len(EFFECTS)) * self.scale[None, :]

    def observe(self, per_pixel, measuring, scaled_priors, full_rate=True) -> None:
        """Learn from the measured items: ``per_pixel`` (n, 3) each item's measured difference per
        changed pixel, ``measuring`` (n, 3) the items measured this frame, ``scaled_priors`` (n, 3)
        the priors they were chosen with (:meth:`apply`'s), ``full_rate`` (n, 3) or a bool: the
        items traced at full rate (a reduced rate changes less: not a sample).  A reflection
        measured with its element's refraction is not a sample either: the glass's pixels where
        both were traced are charged to the refraction (``item_benefit.measure``), so the
        reflection reads about 0 there whatever it changed."""
        if not self.learn:
            return
        scale = self.scale
        raw = finite(np.asarray(scaled_priors, np.float64).reshape(-1, len(EFFECTS)) /
                     np.where(scale > 0, scale, 1.0)[None, :])
        seen = finite(np.asarray(per_pixel, np.float64).reshape(raw.shape))
        measuring = np.asarray(measuring, bool).reshape(raw.shape)
        usable = measuring & np.asarray(full_rate, bool) & (raw > 0)
        usable[:, EFFECTS.index("reflections")] &= ~measuring[:, EFFECTS.index("refractions")]
        for column in np.flatnonzero(usable.any(axis=0)).tolist():
            rows = usable[:, column]
            self.ratios[column].extend((seen[rows, column] / raw[rows, column]).tolist())
            if len(self.ratios[column]) >= MIN_SAMPLES:
                learned = float(np.median(np.fromiter(self.ratios[column], np.float64))) / self.fitted[column] \
                    if self.fitted[column] > 0 else 1.0
                self.learned[column] = min(max(learned, RANGE[0]), RANGE[1])
