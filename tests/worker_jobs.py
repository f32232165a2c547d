"""Job functions for the executor tests, in a module of their own so that a spawned worker
process imports only this (no Taichi) to run them."""

import os


def square_or_die(job: int) -> int:
    """job², except that job 13 kills its worker process (as the OOM killer would)."""
    if job == 13:
        os._exit(9)
    return job * job
