"""Runs over a camera path that replay, sweep, judge or advise (see each module)."""
