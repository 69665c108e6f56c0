"""PHRT operators (filled in by the workflow issue)."""


def register():
    pass


def unregister():
    pass
