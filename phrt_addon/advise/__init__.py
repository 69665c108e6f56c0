"""The tagging advisor's core (bpy-free): what each (element, effect) item is worth per millisecond.

A level designer tags ray tracing candidates; ``phrt advise`` measures, on sampled frames of a
camera path, what each item (one effect of one element, tagged or a temporary candidate made of
an untagged object) removes in LDR-FLIP when traced alone against the raster frame, what it costs,
and how often each selection and the oracle chose it, then recommends one change per item.

- ``items.py``      item names, untagged prospects, the per-item books over the judged frames;
- ``recommend.py``  the recommendation and its reason in words (``keep``, ``untag``, ...);
- ``files.py``      advice.csv / advice.json / advice.md / advice.html;
- ``charts.py``     the ranked bar chart of benefit per ms and the strip of where it mattered;
- ``export.py``     the designer's tags with their measured value, for a game engine's knobs.

The renders are the engine's (``engine/runs/advise.py``), through the oracle's own measurement.
"""
