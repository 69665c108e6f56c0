"""``phrt rescore SWEEP_DIR``: a sweep's recorded choices judged again on its oracle's measurements,
without rendering (``phrt_addon/report/rescore.py``).  Needs no Blender.
"""
from __future__ import annotations

from ..phrt_addon.report import rescore
from .blender_process import UserError


def command_rescore(args):
    try:
        rows, folder = rescore.rescore(args.sweep_dir, args.out)
    except ValueError as error:
        raise UserError(str(error).splitlines()[0]) from None
    print(rescore.markdown(rows), end="")
    print(f"phrt: rescored {len(rows)} runs: {folder / rescore.RESCORE_CSV}")
    return 0
