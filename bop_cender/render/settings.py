"""The renderer's settings in one frozen value (pytorch3d's ``RasterizationSettings`` habit).

Every module of the renderer takes its defaults from :data:`DEFAULT_RENDER_SETTINGS`, so the near plane
and the chunk sizes per job and device are stated once; callers that want others pass their own
:class:`RenderSettings` where a function takes one (:meth:`~bop_cender.pose.backend.Backend.candidate_costs`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class RenderSettings:
    """Near plane and chunk sizes (pixels rendered together bound memory; the best size differs by job and device).

    Attributes:
        near: near plane (mm): geometry closer than this to the camera plane is clipped away.
        scene_chunk_pixels: full-frame pixels per chunk of :func:`~bop_cender.render.rasterizer.render_scene`
            and the square-window renders (2^21 int64 keys: about 16 MB).
        candidate_chunk_pixels_cpu: window pixels per chunk of the cost's candidate atlases on the CPU, small
            enough for the caches, large enough to amortise a chunk's few hundred torch calls (2^18 to 2^20
            measured within 5 %).
        candidate_chunk_pixels_cuda: the same on CUDA (GPUs want large batches; 2^24 int32 keys are 64 MB).
        depth_crop_chunk_pixels: atlas pixels per rasteriser call of the VSD depth crops.
    """

    near: float = 1.0
    scene_chunk_pixels: int = 1 << 21
    candidate_chunk_pixels_cpu: int = 1 << 19
    candidate_chunk_pixels_cuda: int = 1 << 24
    depth_crop_chunk_pixels: int = 1 << 18

    def __post_init__(self) -> None:
        if not self.near > 0:
            raise ValueError(f"near must be positive, got {self.near}")
        for name in ("scene_chunk_pixels", "candidate_chunk_pixels_cpu", "candidate_chunk_pixels_cuda",
                     "depth_crop_chunk_pixels"):  # fmt: skip
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")

    def candidate_chunk_pixels(self, device: torch.device) -> int:
        """The candidate chunk size for ``device``."""
        return self.candidate_chunk_pixels_cuda if device.type == "cuda" else self.candidate_chunk_pixels_cpu


DEFAULT_RENDER_SETTINGS = RenderSettings()
