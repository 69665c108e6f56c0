"""Element names: how a scene's objects, instances and tagged materials are named in the
snapshot, the logs (``selection.csv``'s ``element``) and the UI.  The one place that builds
and parses them (docs/formats.md).

- ``Obj``: a whole object (its faces without a tagged material);
- ``Obj@Parent:id``: an instance of ``Obj`` made by ``Parent`` (``id``: its persistent id);
- ``<either>/Material``: the faces of one tagged material of that object or instance.

A Blender name may hold any of ``/``, ``@`` and ``\\``: inside a name part each is written with
a ``\\`` before it (``Wall/Glass`` the object is ``Wall\\/Glass``; object ``Wall`` with its tagged
material ``Glass`` is ``Wall/Glass``), so two different parts never give one name.  A name
without those characters is written as it is.
"""
from __future__ import annotations

MATERIAL_SEPARATOR = "/"
INSTANCE_SEPARATOR = "@"
ESCAPE = "\\"


def escape(name: str) -> str:
    """A name part with ``\\``, ``/`` and ``@`` escaped."""
    text = str(name).replace(ESCAPE, ESCAPE + ESCAPE)
    return text.replace(MATERIAL_SEPARATOR, ESCAPE + MATERIAL_SEPARATOR).replace(
        INSTANCE_SEPARATOR, ESCAPE + INSTANCE_SEPARATOR)


def unescape(text: str) -> str:
    result, index = [], 0
    while index < len(text):
        if text[index] == ESCAPE and index + 1 < len(text):
            index += 1
        result.append(text[index])
        index += 1
    return "".join(result)


def _unescaped(text: str, separator: str) -> list:
    """Positions of ``separator`` in ``text`` that are not escaped."""
    found, index = [], 0
    while index < len(text):
        if text[index] == ESCAPE:
            index += 2
            continue
        if text[index] == separator:
            found.append(index)
        index += 1
    return found


def object_element(object_name: str, parent_name: str | None = None, persistent_id: int | None = None) -> str:
    """The element of an object (``parent_name`` None) or of an instance of it."""
    if parent_name is None:
        return escape(object_name)
    return f"{escape(object_name)}{INSTANCE_SEPARATOR}{escape(parent_name)}:{persistent_id}"


def material_element(base: str, material_name: str) -> str:
    """The element made of the faces of a tagged material of ``base`` (an object element)."""
    return f"{base}{MATERIAL_SEPARATOR}{escape(material_name)}"


def base_element(element: str) -> str | None:
    """The object element a material element belongs to, None for an object element."""
    positions = _unescaped(element, MATERIAL_SEPARATOR)
    return element[: positions[-1]] if positions else None


def element_object_name(element: str, object_names) -> str | None:
    """The object an element name belongs to (``object_names``: a container of the existing
    object names), or None."""
    base = base_element(element)
    head = element if base is None else base
    at = _unescaped(head, INSTANCE_SEPARATOR)
    name = unescape(head[: at[0]] if at else head)
    return name if name in object_names else None
