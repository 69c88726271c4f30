"""Pictures of a run: off-screen GGUI frames (:mod:`.frame`), their H.264 video and
the recorder that draws a running simulation (:mod:`.video`), the process's
hidden window and Vulkan probe (:mod:`.window`), the text strip's bitmap font
(:mod:`.font`) and the live viewer (:mod:`.viewer`).

Importing this package loads Taichi; :func:`vulkan_status` says whether
off-screen rendering works here.
"""
from .frame import (FLUID_PLAIN, OUTLINE_DARK, SPECIES_COLORS, TEXT_COLOR, WALL_GREY, Renderer,
                    colormap)
from .video import VideoRecorder, VideoWriter
from .window import close_window, vulkan_status

__all__ = ["FLUID_PLAIN", "OUTLINE_DARK", "SPECIES_COLORS", "TEXT_COLOR", "WALL_GREY",
           "Renderer", "VideoRecorder", "VideoWriter", "close_window", "colormap",
           "vulkan_status"]
