"""What each traced item changed (select/item_benefit.measure) and each traced element
(select/benefit.measure_differences): only the traced pixels looked at (benefit.owned_change), the
same sums as frame-sized maps of each pixel's owner (the transparent layer's element where both
layers traced a pixel)."""
from types import SimpleNamespace

import numpy as np

from phrt.phrt_addon.select import benefit, item_benefit


def owners_by_maps(layers, traced, change, n):
    """The measure by frame-sized owner maps (the former implementation): the reference."""
    flat_change = change.reshape(-1, change.shape[-1])
    result = np.zeros((n, 3))
    for effect, column in (("reflections", 1), ("refractions", 2)):
        owner = np.full(len(flat_change), -1, np.int64)
        for layer_name in ("opaque", "transparent"):
            pixels = layers[layer_name]
            element_at = np.full(len(flat_change), -1, np.int64)
            element_at[pixels.flat] = pixels.element
            if effect == "reflections" and layer_name in traced.reflection:
                where = traced.reflection[layer_name][0]
                if layer_name == "transparent" and traced.refraction is not None:
                    where = np.setdiff1d(where, traced.refraction[0])
                owner[where] = element_at[where]
            if effect == "refractions" and layer_name == "transparent" and traced.refraction is not None:
                owner[traced.refraction[0]] = element_at[traced.refraction[0]]
        mine = np.flatnonzero((owner >= 0) & (owner < n))
        result[:, column] = np.bincount(owner[mine], weights=flat_change[mine, 0], minlength=n)[:n]
    return result


HEIGHT, WIDTH, N = 24, 32, 6


def random_frame(rng, case):
    """(layers, traced, change, snapshot) of a random frame: both layers overlap; the transparent
    layer's reflection on odd cases, a refraction unless the case is a multiple of 3."""
    layers = {}
    for name, share in (("opaque", 0.9), ("transparent", 0.3)):
        flat = np.flatnonzero(rng.random(HEIGHT * WIDTH) < share)
        layers[name] = SimpleNamespace(flat=flat, element=rng.integers(0, N, len(flat)))

    def pick(name, share):
        return np.sort(rng.choice(layers[name].flat, int(share * len(layers[name].flat)), replace=False))

    reflection = {"opaque": (pick("opaque", 0.4), None)}
    if case % 2:
        reflection["transparent"] = (pick("transparent", 0.5), None)
    refraction = (pick("transparent", 0.6), None) if case % 3 else None
    traced = SimpleNamespace(reflection=reflection, refraction=refraction, shadow_visibility={})
    change = rng.random((HEIGHT, WIDTH, 2)).astype(np.float32)
    snapshot = SimpleNamespace(elements=[SimpleNamespace(shadows=False)] * N)
    return layers, traced, change, snapshot


def test_the_traced_pixels_sums_equal_the_owner_maps_on_random_frames():
    rng = np.random.default_rng(5)
    for case in range(40):
        layers, traced, change, snapshot = random_frame(rng, case)
        chosen = np.ones((N, 3), bool)
        chosen[:, 0] = False  # no shadows: their sums are benefit.shadow_differences' own
        got = item_benefit.measure(snapshot, layers, change, traced, chosen, [None] * N)
        assert np.allclose(got, owners_by_maps(layers, traced, change, N) * chosen), case


def test_an_empty_layer_owns_nothing():
    empty = SimpleNamespace(flat=np.zeros(0, np.int64), element=np.zeros(0, np.int64))
    assert benefit.elements_at(empty, np.array([3, 7])).tolist() == [-1, -1]


def test_the_error_aware_relevances_sums_equal_the_owner_maps_too():
    """benefit.measure_differences (the `error` relevance): one sum per element, the transparent
    layer's reflection then its refraction owning a pixel over the opaque layer's reflection."""
    rng = np.random.default_rng(9)
    for case in range(30):
        layers, traced, change, snapshot = random_frame(rng, case)
        flat_change = change.reshape(-1, 2)
        owner = np.full(HEIGHT * WIDTH, -1, np.int64)
        for name in ("opaque", "transparent"):
            element_at = np.full(HEIGHT * WIDTH, -1, np.int64)
            element_at[layers[name].flat] = layers[name].element
            wheres = ([traced.reflection[name][0]] if name in traced.reflection else []) + \
                ([traced.refraction[0]] if name == "transparent" and traced.refraction is not None else [])
            for where in wheres:
                owner[where] = element_at[where]
        mine = owner >= 0
        expected = np.bincount(owner[mine], weights=flat_change[mine, 0], minlength=N)
        got = benefit.measure_differences(snapshot, layers, change, traced, np.zeros(N, bool), [None] * N)
        assert np.allclose(got, expected), case
