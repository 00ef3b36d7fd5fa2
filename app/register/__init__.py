"""Registration: the video's frames against the scene, past the GNSS bound (render-and-compare
keyframes, fused with the sensors). `registered_track` is the `registered` pose source."""

from app.register.fuse import Correction, FuseSettings, Keyframe
from app.register.keyframe import Matcher, MatchSettings, PoseFix
from app.register.solve import (
    Registrar,
    Registration,
    RegistrationSettings,
    default_prior,
    registered_track,
)

__all__ = [
    "Correction",
    "FuseSettings",
    "Keyframe",
    "MatchSettings",
    "Matcher",
    "PoseFix",
    "Registrar",
    "Registration",
    "RegistrationSettings",
    "default_prior",
    "registered_track",
]
