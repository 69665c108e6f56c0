"""Run folders: writing and reading RUN_DIRs, sweep plans and the executors that run them; one
writer per folder (``lock.py``), files that appear whole (``atomic.py``), taking a folder for a
replay (``folder.py``) and what a run records of its work (``work.py``)."""
