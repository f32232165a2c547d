"""A run's progress bar on stderr: frames done, simulated time and the estimated time left.
Silent with ``--quiet`` or when stderr is not a terminal (logs, CI, pipes)."""

import sys

from tqdm import tqdm


class Progress:
    """One bar per run; ``update(t)`` after each frame, with the simulated time ``t`` [s]."""

    def __init__(self, label: str, frame_count: int, quiet: bool):
        self.bar = tqdm(total=frame_count, desc=label, unit="frame", file=sys.stderr,
                        disable=quiet or not sys.stderr.isatty(), dynamic_ncols=True,
                        bar_format="{desc}: {bar} {n_fmt}/{total_fmt} frames{postfix} "
                                   "[{elapsed}<{remaining}]")

    def update(self, t: float) -> None:
        self.bar.set_postfix_str(f"t = {t:.2f} s", refresh=False)
        self.bar.update(1)

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.bar.close()
