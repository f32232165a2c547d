"""A sweep's contact sheet: one tile per run, in the table's order, its thumbnail (the last
frame) titled with the grid's values; a run that did not finish is titled in red with its
status, over its last whole frame when it has one, else a grey tile."""

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from taichi_cloth.output.files import read_png
from taichi_cloth.studies.compare_plots import save

TILE_INCHES = 2.6  # width of a tile
MAX_COLUMNS = 8
FAILED_GREY = 0.85


def tile_title(row: dict, keys: list[str]) -> str:
    """The run's grid values, one ``key = value`` a line (the key's last part), then its status
    when it did not finish."""
    lines = [f"{key.rsplit('.', 1)[-1]} = {row[key]}" for key in keys]
    if row.get("exit_code", 1) != 0:
        lines.append(f"{row.get('status', 'failed')} (exit {row.get('exit_code')})")
    return "\n".join(lines)


def write_contact_sheet(target: Path, plan, rows: list[dict]) -> None:
    """``contact_sheet.png``: the runs of ``plan`` (``rows``: the table's rows in order)."""
    keys = [key for key, _ in plan.grid]
    columns = min(MAX_COLUMNS, len(rows))
    lines = len(keys) + 1
    aspect = 3 / 4
    figure = Figure(figsize=(TILE_INCHES * columns,
                             (TILE_INCHES * aspect + 0.16 * lines) * math.ceil(len(rows) / columns)))
    panels = np.atleast_1d(figure.subplots(math.ceil(len(rows) / columns), columns)).ravel()
    for axes in panels:
        axes.set_axis_off()
    for axes, row in zip(panels, rows):
        thumbnail = Path(row.get("folder", "")) / row.get("thumbnail", "")
        if row.get("thumbnail") and thumbnail.is_file():  # (an unstable run's: its last frame)
            axes.imshow(read_png(thumbnail))
        else:
            axes.imshow(np.full((3, 4), FAILED_GREY), cmap="gray", vmin=0, vmax=1)
        failed = row.get("exit_code", 1) != 0
        axes.set_title(tile_title(row, keys), fontsize=8, color="tab:red" if failed else "black")
    save(figure, target)
