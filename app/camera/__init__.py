"""How a camera sees: pinhole intrinsics (intrinsics), real lenses (lens) and the bundled
gyroflow profiles chosen for a camera (profiles), the camera with its pose and matrices
(pinhole), positions and attitudes at any time (trajectory: the paper's Eq. 3-4) and which video
frame is shown at a media time (frame_time). Pure numpy; it reads no session."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
