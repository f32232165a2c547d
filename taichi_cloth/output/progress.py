"""A run's progress bar on stderr: frames done, simulated time and the estimated time left.
Silent with ``--quiet`` or when stderr is not a terminal (logs, CI, pipes)."""

import sys

from tqdm import tqdm


def shows(quiet: bool) -> bool:
    """Whether progress is shown: not ``--quiet`` and stderr a terminal."""
    return not quiet and sys.stderr.isatty()


def announce(label: str, text: str, quiet: bool) -> None:
    """One status line before the bar exists (building, compiling, settling), so that the
    seconds before the first frame are not silent."""
    if shows(quiet):
        sys.stderr.write(f"{label}: {text}\n")
        sys.stderr.flush()


class Progress:
    """One bar per run; ``update(t)`` after each frame, with the simulated time ``t`` [s]. Until
    the second frame it says that the step's kernels are compiling (the first launch of each
    compiles it: seconds on a fresh machine)."""

    def __init__(self, label: str, frame_count: int, quiet: bool):
        self.bar = tqdm(total=frame_count, desc=label, unit="frame", file=sys.stderr,
                        disable=not shows(quiet), dynamic_ncols=True,
                        bar_format="{desc}: {bar} {n_fmt}/{total_fmt} frames{postfix} "
                                   "[{elapsed}<{remaining}]")
        self.bar.set_postfix_str("compiling the step's kernels", refresh=True)

    def update(self, t: float) -> None:
        postfix = f"t = {t:.2f} s" + ("; compiling the step's kernels" if self.bar.n == 0 else "")
        self.bar.set_postfix_str(postfix, refresh=False)
        self.bar.update(1)

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.bar.close()
