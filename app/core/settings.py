"""Frozen settings with units. Pure data: read by render, playback and ui alike."""

from __future__ import annotations

from dataclasses import dataclass

from app.core.constants import (
    DEFAULT_ALPHA,
    DEFAULT_DEPTH_BIAS_M,
    DEFAULT_DEPTH_LONG_SIDE_PX,
    DEFAULT_DEPTH_SLOPE_BIAS,
)


@dataclass(frozen=True)
class ProjectionSettings:
    """How the video is projected onto the model.

    enabled: project at all; alpha: video opacity in [0, 1] (0 = model only, 1 = video only);
    bias_constant_m: constant depth bias, metres; bias_slope: slope-scaled bias in depth-map
    texels of surface slope; neighbourhood: the paper's nine-case rule; depth_long_side: depth
    map texels on the video's long side (the short side follows the video's aspect).
    """

    enabled: bool = True
    alpha: float = DEFAULT_ALPHA
    bias_constant_m: float = DEFAULT_DEPTH_BIAS_M
    bias_slope: float = DEFAULT_DEPTH_SLOPE_BIAS
    neighbourhood: bool = True
    depth_long_side: int = DEFAULT_DEPTH_LONG_SIDE_PX

    def __post_init__(self) -> None:
        if not 0.0 <= self.alpha <= 1.0:
            raise ValueError(f"alpha must be in [0, 1], got {self.alpha}")
        if self.bias_constant_m < 0 or self.bias_slope < 0:
            raise ValueError("depth bias terms must be >= 0")
        if not 16 <= self.depth_long_side <= 16384:
            raise ValueError(
                f"depth map size must be in [16, 16384] texels, got {self.depth_long_side}"
            )


@dataclass(frozen=True)
class OverlaySettings:
    """What is drawn over the scene: the projector's frustum (lines out to `frustum_length_m`),
    the trajectory polyline, and the projection error in metres as colours on the model."""

    frustum: bool = True
    trajectory: bool = True
    frustum_length_m: float = 25.0
    error_map: bool = False  # colour the model by projection error (needs a truth camera)
    error_scale_m: float = 4.0  # error at the red end of the colour ramp, metres
    error_map_texels: int = 512  # the truth position map's long side
