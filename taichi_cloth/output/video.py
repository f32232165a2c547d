"""Videos of the frames: H.264 mp4 through imageio with imageio-ffmpeg, or a looping GIF."""

from contextlib import contextmanager
from pathlib import Path

import imageio
import imageio.v3 as iio
import numpy as np

from taichi_cloth.output.files import atomic_path


@contextmanager
def video_writer(target: Path, video_format: str, fps: float):
    """Yield ``append(image)`` for (H, W, 3) uint8 frames of a video at ``fps``: an H.264 mp4
    (ffmpeg through imageio-ffmpeg, yuv420p, so an odd width or height loses its last pixel
    column or row; "fast start": the index (moov) before the frames (mdat), so a player starts
    while the file is still arriving) or a looping GIF. The file appears at ``target`` only if the block ends
    without an error."""
    with atomic_path(target, f".{video_format}") as temporary:
        if video_format == "gif":
            frames = []
            yield frames.append
            iio.imwrite(temporary, np.stack(frames), extension=".gif", duration=1000.0 / fps,
                        loop=0)
            return
        writer = imageio.v2.get_writer(temporary, format="FFMPEG", mode="I", fps=fps,
                                       codec="libx264", pixelformat="yuv420p", quality=8,
                                       macro_block_size=1, ffmpeg_log_level="error",
                                       output_params=["-movflags", "+faststart"])
        try:
            yield lambda image: writer.append_data(
                image[:image.shape[0] // 2 * 2, :image.shape[1] // 2 * 2])
        finally:
            writer.close()
