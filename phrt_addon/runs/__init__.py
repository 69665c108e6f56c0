"""Run folders: one writer per folder (``lock.py``), files that appear whole (``atomic.py``), taking
a folder for a replay (``folder.py``) and what a run records of its work (``work.py``)."""
