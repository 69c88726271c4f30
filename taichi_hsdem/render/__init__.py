"""Pictures of a run: off-screen GGUI frames, the MP4 writer and the live viewer."""
from .frame import (FLUID_PLAIN, OUTLINE_DARK, SPECIES_COLORS, TEXT_COLOR, WALL_GREY,  # noqa: F401
                    Renderer, VideoWriter, _text_mask, close_window, colormap,
                    vulkan_status)
