"""Pose at any time (paper 2.1.3): GNSS position by cubic Hermite interpolation on time, position
and velocity at both ends of each interval (Eq. 3), attitude by quaternion slerp.

Eq. 4, corrected (DESIGN.md): velocity east/north/up (m/s) at a fix becomes geodetic rates
dphi/dt = v_N / (M + h), dlambda/dt = v_E / ((N + h) cos phi), dh/dt = v_U, with the meridian
radius M and prime-vertical radius N (app.geodesy.enu) at the fix's latitude. Where a log has no velocity,
it is estimated from the neighbouring fixes (central differences in the local ENU frame).

Gaps. An interval between fixes longer than GAP_MIN_S and GAP_FACTOR median intervals (an
outage, metadata sent every 30-100 s) is crossed by a straight line between its fixes, not by
the cubic (which, with the velocities at its ends, can stray hundreds of metres across a long
one), and the velocities are estimated within the stretches between gaps, never across one.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from app.core.constants import GAP_FACTOR, GAP_MIN_S, JUMP_SLACK_M, MAX_SPEED_MPS
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame, meridian_radius, prime_vertical_radius

FloatArray = npt.NDArray[np.float64]


def estimate_velocity(t: FloatArray, enu: FloatArray) -> FloatArray:
    """(N, 3) m/s from positions (N, 3) m at times t (s): central differences inside, one-sided at
    the ends (numpy.gradient with uneven spacing)."""
    if len(t) < 2:
        return np.zeros_like(enu)
    return np.gradient(enu, t, axis=0, edge_order=1)


def gap_limit_s(t: npt.ArrayLike) -> float:
    """Seconds beyond which an interval between fixes at times t (s) is a gap: GAP_MIN_S, or
    GAP_FACTOR times the median interval where that is longer."""
    dt = np.diff(np.asarray(t, np.float64))
    return max(GAP_MIN_S, GAP_FACTOR * float(np.median(dt))) if len(dt) else GAP_MIN_S


def gap_intervals(t: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """(N-1,) which intervals between fixes at times t (s) are gaps: longer than gap_limit_s."""
    dt = np.diff(np.asarray(t, np.float64))
    return dt > gap_limit_s(t)


def breaks(t: npt.ArrayLike, enu: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """(N-1,) which intervals between fixes at times t (s), positions enu (N, 3) m, no curve
    crosses: gaps (gap_intervals) and steps faster than MAX_SPEED_MPS horizontally, by
    JUMP_SLACK_M more (a jump the readers kept: app.io.streams.plausible_fixes)."""
    t = np.asarray(t, np.float64)
    moved = np.linalg.norm(np.diff(np.asarray(enu, np.float64)[:, :2], axis=0), axis=1)
    return gap_intervals(t) | (moved > MAX_SPEED_MPS * np.diff(t) + JUMP_SLACK_M)


def gaps_said(t: npt.ArrayLike) -> str:
    """One line on the gaps between fixes at times t (s) (gap_intervals): how many, the longest
    and where it begins; '' where there is none."""
    t = np.asarray(t, np.float64)
    gaps = gap_intervals(t)
    if not gaps.any():
        return ""
    dt = np.where(gaps, np.diff(t), 0.0)
    k = int(np.argmax(dt))
    return (
        f"{int(gaps.sum())} gap(s) between positions, the longest {dt[k]:.1f} s from t = "
        f"{t[k]:.1f} s: crossed by a straight line between the fixes around it, not a curve"
    )


def geodetic_rates(lat_deg: FloatArray, h_m: FloatArray, vel_enu: FloatArray) -> FloatArray:
    """(N, 3) of dphi/dt, dlambda/dt (rad/s) and dh/dt (m/s) from ENU velocities (Eq. 4 corrected)."""
    phi = np.radians(lat_deg)
    dphi = vel_enu[:, 1] / (meridian_radius(lat_deg) + h_m)
    dlam = vel_enu[:, 0] / ((prime_vertical_radius(lat_deg) + h_m) * np.cos(phi))
    return np.column_stack([dphi, dlam, vel_enu[:, 2]])


def hermite(
    t0: FloatArray,
    t1: FloatArray,
    p0: FloatArray,
    p1: FloatArray,
    v0: FloatArray,
    v1: FloatArray,
    t: FloatArray,
) -> FloatArray:
    """Cubic phi(t) = a0 + a1 s + a2 s^2 + a3 s^3 through (t0, p0, v0) and (t1, p1, v1) (Eq. 3),
    written in Hermite basis on s = t - t0; broadcast over arrays."""
    h = t1 - t0
    s = (t - t0) / h
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1


@dataclass(frozen=True)
class PositionTrack:
    """GNSS fixes with velocities, interpolated on demand. t (N,) s; lat/lon deg; h m; vel (N, 3) m/s ENU."""

    t: FloatArray
    lat: FloatArray
    lon: FloatArray
    h: FloatArray
    vel_enu: FloatArray

    @classmethod
    def from_fixes(
        cls,
        t: npt.ArrayLike,
        lat: npt.ArrayLike,
        lon: npt.ArrayLike,
        h: npt.ArrayLike,
        vel_enu: npt.ArrayLike | None = None,
    ) -> PositionTrack:
        t, lat, lon, h = (np.asarray(a, np.float64) for a in (t, lat, lon, h))
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            raise ValueError("need at least 2 fixes with strictly increasing times")
        if vel_enu is not None:
            return cls(t, lat, lon, h, np.asarray(vel_enu, np.float64))
        frame = LocalFrame(float(lat[0]), float(lon[0]), float(h[0]))
        enu = frame.geodetic_to_enu(lat, lon, h)
        vel = np.zeros_like(enu)
        gaps = breaks(t, enu)
        cuts = np.flatnonzero(gaps) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(t)], strict=True):
            vel[a:b] = estimate_velocity(t[a:b], enu[a:b])  # within a stretch only
        track = cls(t, lat, lon, h, vel)
        track.__dict__["_gaps"] = gaps  # the cached breaks (_gaps), found once here
        return track

    @cached_property
    def _hermite_nodes(self) -> tuple[FloatArray, FloatArray]:
        """(lat rad, lon rad, h m) and their rates at the fixes: computed once, used per query."""
        p = np.column_stack([np.radians(self.lat), np.radians(self.lon), self.h])
        return p, geodetic_rates(self.lat, self.h, self.vel_enu)

    def geodetic_at(self, tq: npt.ArrayLike) -> FloatArray:
        """(M, 3) latitude deg, longitude deg, height m at times tq (held outside the fixes' span)."""
        tq = np.clip(np.atleast_1d(np.asarray(tq, np.float64)), self.t[0], self.t[-1])
        i = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self.t) - 2)
        p, rates = self._hermite_nodes
        t0, t1 = self.t[i, None], self.t[i + 1, None]
        out = hermite(t0, t1, p[i], p[i + 1], rates[i], rates[i + 1], tq[:, None])
        across = self._gaps[i]
        if across.any():  # a straight line between the fixes around a gap or a step
            s = (tq[across, None] - t0[across]) / (t1[across] - t0[across])
            out[across] = (1 - s) * p[i[across]] + s * p[i[across] + 1]
        return np.column_stack([np.degrees(out[:, 0]), np.degrees(out[:, 1]), out[:, 2]])

    @cached_property
    def _gaps(self) -> npt.NDArray[np.bool_]:
        """(N-1,) the intervals no curve crosses (breaks), in the frame at the first fix."""
        frame = LocalFrame(float(self.lat[0]), float(self.lon[0]), float(self.h[0]))
        return breaks(self.t, frame.geodetic_to_enu(self.lat, self.lon, self.h))


# Display rotation (the clockwise "rotate" tag a phone writes) -> camera roll about the device z
# axis, for a back camera whose sensor's long side runs along the device's y axis (phones do this):
# portrait upright is stored landscape with rotate=90.
_CAMERA_ROLL = {90: 0.0, 270: 180.0, 0: -90.0, 180: 90.0}


def device_to_camera(display_rotation_deg: int) -> FloatArray:
    """Quaternion of the camera frame (of the displayed video) in the device frame.

    The back camera in portrait coincides with the device frame (DESIGN.md). Stored landscape
    frames with rotate=90 are portrait upright: camera = device. rotate=0: the phone was turned
    counter-clockwise (top to the left), so image right = device -y: a -90 deg turn about z.
    rotate=180: top to the right, +90 deg; rotate=270: upside down, 180 deg.
    """
    r = int(display_rotation_deg) % 360
    if r not in _CAMERA_ROLL:
        raise ValueError(
            f"display rotation must be a multiple of 90 degrees, got {display_rotation_deg}"
        )
    return rotations.about_z(_CAMERA_ROLL[r])


@dataclass(frozen=True)
class PoseTrack:
    """Camera pose at any time: positions from a PositionTrack, device attitude by slerp between
    attitude samples, then the fixed device -> camera rotation. Times in session seconds."""

    frame: LocalFrame
    positions: PositionTrack
    t_att: FloatArray
    q_device: FloatArray
    q_dev_to_cam: FloatArray

    @cached_property
    def _slerp(self) -> rotations.Interpolator:
        """Built once: the viewer asks for one time per frame."""
        return rotations.Interpolator(self.t_att, self.q_device)

    def at(self, tq: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(ENU (M, 3) m, geodetic (M, 3) deg/deg/m, camera -> ENU quaternions (M, 4)) at session
        times tq (s). Callers outside this module go through app.session.camera_track.CameraTrack."""
        geo = self.positions.geodetic_at(tq)
        enu = self.frame.geodetic_to_enu(geo[:, 0], geo[:, 1], geo[:, 2])
        q_dev = self._slerp(np.atleast_1d(tq))
        q_cam = rotations.canonical(rotations.multiply(q_dev, self.q_dev_to_cam))
        return enu, geo, q_cam
