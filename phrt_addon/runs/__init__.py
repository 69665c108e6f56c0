"""Run folders: writing and reading RUN_DIRs, sweep plans and the executors that run them."""
