"""Element names: how a scene's objects, instances and tagged materials are named in the
snapshot, the logs (``selection.csv``'s ``element``) and the UI.  The one place that builds
and parses them (docs/formats.md).

- ``Obj``: a whole object (its faces without a tagged material);
- ``Obj@Parent:id``: an instance of ``Obj`` made by ``Parent`` (``id``: its persistent id);
- ``<either>/Material``: the faces of one tagged material of that object or instance.
"""
from __future__ import annotations

MATERIAL_SEPARATOR = "/"
INSTANCE_SEPARATOR = "@"


def object_element(object_name: str, parent_name: str | None = None, persistent_id: int | None = None) -> str:
    """The element of an object (``parent_name`` None) or of an instance of it."""
    if parent_name is None:
        return object_name
    return f"{object_name}{INSTANCE_SEPARATOR}{parent_name}:{persistent_id}"


def material_element(base: str, material_name: str) -> str:
    """The element made of the faces of a tagged material of ``base`` (an object element)."""
    return f"{base}{MATERIAL_SEPARATOR}{material_name}"


def base_element(element: str) -> str | None:
    """The object element a material element belongs to, None for an object element."""
    if MATERIAL_SEPARATOR in element:
        return element.rsplit(MATERIAL_SEPARATOR, 1)[0]
    return None


def element_object_name(element: str, object_names) -> str | None:
    """The object an element name belongs to.  ``object_names`` is a container of the
    existing object names (exact names win over parsing: names may hold the separators)."""
    if element in object_names:
        return element
    base = base_element(element)
    if base is not None:
        if base in object_names:
            return base
        element = base
    if INSTANCE_SEPARATOR in element:
        head = element.split(INSTANCE_SEPARATOR, 1)[0]
        if head in object_names:
            return head
    return None
