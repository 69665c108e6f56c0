"""Element names are unique by construction (phrt_addon/naming.py): separators inside Blender
names are escaped, so an object named ``Wall/Glass`` and the material ``Glass`` of object
``Wall`` are two elements, and every name parses back to its object."""
import pytest

from phrt.phrt_addon import naming


def test_an_object_named_like_a_material_element_is_another_element():
    assert naming.object_element("Wall/Glass") == "Wall\\/Glass"
    assert naming.material_element(naming.object_element("Wall"), "Glass") == "Wall/Glass"
    assert naming.object_element("Wall/Glass") != naming.material_element(naming.object_element("Wall"), "Glass")


@pytest.mark.parametrize("obj, material, parent", [
    ("Wall", "Glass", None), ("Wall/Glass", "Frame", None), ("A@B", "x/y", None), ("back\\slash", "m\\", None),
    ("Tree", "Leaf", "Forest@1"), ("Rock/1", "Moss@2", "Sca/tter"), ("plain", "", None)])
def test_every_name_parses_back_to_its_object_and_base(obj, material, parent):
    base = naming.object_element(obj, parent, 7 if parent else None)
    element = naming.material_element(base, material)
    assert naming.base_element(element) == base
    assert naming.base_element(base) is None
    objects = {obj, "Wall", "Glass", "Forest@1"}
    assert naming.element_object_name(element, objects) == obj
    assert naming.element_object_name(base, objects) == obj
    assert naming.unescape(naming.escape(obj)) == obj


def test_names_from_different_parts_never_collide():
    parts = ["a", "a/b", "b", "a@b", "a\\", "\\/", "/", "@", "x:1"]
    names = set()
    count = 0
    for obj in parts:
        for material in parts:
            names.add(naming.material_element(naming.object_element(obj), material))
            count += 1
        names.add(naming.object_element(obj))
        count += 1
    assert len(names) == count
