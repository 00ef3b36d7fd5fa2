"""GNSS fixes and registered keyframes carried by the IMU's motion (issue 52): each fix is tested
against the motion the accelerometer integrates since the fixes before it, and where the fixes
are rejected or missing the track is carried by that motion between the fixes and keyframes
around, with a standard deviation that grows away from them and shrinks at each.

The accelerometer's specific force, turned into the world by the track's device attitude, less
gravity, is the platform's acceleration (`Motion`, ENU m/s^2). A linear Kalman filter per axis
(east, north, up) over [position, velocity, the acceleration's error, the GNSS's own error] is
driven by it. The acceleration's error walks, faster while the platform's acceleration changes
(entering, flying and leaving a turn: an attitude filter takes part of a sustained acceleration
for gravity, so its tilt, and so the world acceleration, errs by a share of it that follows the
turn: on a simulated survey's 4 m/s^2 turns, 1 m/s^2 for seconds; on a steady orbit 0.3 m/s^2
turning with the aircraft). The GNSS error is a first-order Gauss-Markov process of the fixes'
stated accuracy (1 sigma per axis, twice that in height, correlated over gnss_tau_s, as the
simulator's and a phone's), plus a white part: a share of that accuracy, and all of what the
stated accuracy exceeds the fixes' usual one by (multipath comes and goes within seconds, and a
receiver says so by a larger accuracy). A fix measures the position plus the GNSS error; a
registered keyframe the position alone.

`check_against_imu` runs the filter forward over the fixes alone. Each fix is tested before it
is used, against the state after the fix before it and against the states windows_s seconds
before it carried on by the IMU alone (a drag-off the one-step test would let the filter follow
a little at a time stands out over a window): beyond n_sigma of the predicted spread
(horizontally the chi-square of east and north, the height on its own) it is rejected and not
used, the fixes inside a window that failed are taken back, and the filter carries on by the
IMU until probation fixes in a row pass again. The lies are formed and named as the scene's test
forms them (app.register.gnss.lies_of, witness `imu`): a frozen fix while the IMU says the
platform flies on, a replay whose motion is not the platform's, a jump and a drag-off whose
acceleration the IMU did not feel are caught so, with no scene, for as long as the IMU alone can
tell a lie from its own drift (seconds: its spread grows as the cube of the time and faster; a
drag-off of 1 or 2 m/s hides in the GNSS's own wander, and the scene's keyframes catch it).
`carry` runs the filter forward and back (Rauch-Tung-Striebel) over the fixes kept, the
registered keyframes and, without an IMU, the velocities the video's own motion measured where
neither reaches (app.register.flow_motion): the position, its standard deviation per axis and
the GNSS error at any time (`Carried`). With an IMU, a drag-off's fixes are used too, as the
position plus the GNSS error plus the drag's offset, whose offset and rate are two more states
learnt from the keyframes under it and the IMU: where no keyframe registers (a turn over
grass), its fixes' motion less the drag's line carries the track, not the IMU alone. Times
are session seconds; positions local ENU metres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import numpy.typing as npt

from app.camera.fixes import FixStatus
from app.camera.trajectory import PoseTrack, PositionTrack, gap_intervals, gap_limit_s, hermite
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.register.flow_motion import Flow, Seen, video_flow
from app.register.fuse import Correction, Keyframe
from app.register.gnss import (
    DISAGREES,
    IMU,
    CheckSettings,
    GnssCheck,
    check_fixes,
    lies_of,
)
from app.session.camera_track import CameraTrack
from app.session.model import Session

FloatArray = npt.NDArray[np.float64]
STANDARD_GRAVITY = 9.80665  # m/s^2 (the accelerometer's g, ISO 80000-3)


@dataclass(frozen=True)
class InertialSettings:
    """step_s: the filter's nodes lie at most this far apart (s); acc_noise: the world
    acceleration's white error (m/s^2/sqrt(Hz)); bias_walk: how fast its slow error walks
    (m/s^2/sqrt(s)), plus bias_walk_per_jerk (s^2/sqrt(s)) times how fast the horizontal
    acceleration changes (its jerk, m/s^3: the module docstring); bias0: that error's spread
    at the start (m/s^2); no_imu_noise: the white error where there is no accelerometer
    (m/s^2/sqrt(Hz): the platform keeps its velocity, give or take; a drone weaving at 9 m/s,
    4 m/s^2 at most, is carried 6 s between the measurements around with a median error of
    1.1 times its standard deviation at 2, 2.4 times at 1: docs/ACCURACY.md); gnss_tau_s: the
    GNSS error's correlation time (s); white_share: its white part, a share of the stated accuracy;
    v_ratio: the height's accuracy against the stated horizontal one; accuracy_m: the accuracy
    (m) where the fixes state none; key_sigma_m: a registered keyframe's position error (m, each
    axis; the registered pose's, app.solve.uncertainty); n_sigma: the IMU test's threshold
    (standard deviations of the innovation: 5.5 is a chance of 3e-7 a fix for the horizontal
    chi-square); v0_sigma: the velocity's spread at the start (m/s); windows_s: besides the fix
    before, each fix is tested against the state these many seconds before it, carried by the
    IMU alone (s); probation: after a fix failed, this many in a row must pass before one is
    used again (a lie that the filter's growing spread lets one fix through does not pull it);
    drag_speed0: a drag-off's rate's spread where it begins (m/s, each axis); how fast that
    rate walks (m/s/sqrt(s)): drag_walk_onset until its alarm (it began somewhere between
    where it was dated and there), drag_walk after; its offset's spread where it begins: twice
    the fix's accuracy (`carry`'s drags). Tuned on simulated orbits and surveys
    (docs/ACCURACY.md, issue 52): no alarm on 20 clean
    sessions with multipath bursts."""

    step_s: float = 0.25
    acc_noise: float = 0.01
    bias_walk: float = 0.03
    bias_walk_per_jerk: float = 0.3
    bias0: float = 0.5
    no_imu_noise: float = 2.0
    gnss_tau_s: float = 30.0
    white_share: float = 0.2
    v_ratio: float = 2.0
    accuracy_m: float = 5.0
    key_sigma_m: float = 0.3
    n_sigma: float = 5.5
    v0_sigma: float = 2.0
    windows_s: tuple[float, ...] = (3.0, 8.0)
    probation: int = 3
    drag_speed0: float = 10.0
    drag_walk_onset: float = 1.0
    drag_walk: float = 0.1


@dataclass(frozen=True)
class Motion:
    """The platform's acceleration: t (S,) session s, acc (S, 3) ENU m/s^2 (gravity removed);
    felt: measured (False: no accelerometer, taken as zero). Integrated once: V(t) = the
    integral of acc from t[0], X(t) = the integral of V (trapezoids between samples, the
    acceleration zero outside them)."""

    t: FloatArray
    acc: FloatArray
    felt: bool = True

    @classmethod
    def of(
        cls,
        t_acc: npt.ArrayLike,
        acc_device: npt.ArrayLike,
        t_att: npt.ArrayLike,
        q_att: npt.ArrayLike,
    ) -> Motion:
        """From an accelerometer (times t_acc (S,) s, specific force acc_device (S, 3) m/s^2 in
        the device frame) and the device attitude (times t_att (A,) s, device -> ENU
        quaternions (A, 4), slerped): q f - (0, 0, g)."""
        t = np.asarray(t_acc, np.float64)
        q = rotations.slerp(t_att, q_att, t)
        up = rotations.rotate(q, np.asarray(acc_device, np.float64).reshape(-1, 3))
        return cls(t, up - [0.0, 0.0, STANDARD_GRAVITY])

    def turned(self, rotvec: npt.ArrayLike, span_s: tuple[float, float] | None = None) -> Motion:
        """The acceleration as it would be under an attitude turned world-side by rotvec (3,)
        rad (a registration's rotation correction: R q f - g = R (acc + g) - g), over the
        samples inside span_s (session s, a sample either side kept; None: all)."""
        t, acc = self.t, self.acc
        if span_s is not None:
            a = max(int(np.searchsorted(t, span_s[0])) - 1, 0)
            b = min(int(np.searchsorted(t, span_s[1], side="right")) + 1, len(t))
            t, acc = t[a:b], acc[a:b]
        if not self.felt or len(t) < 2:
            return self
        g = np.array([0.0, 0.0, STANDARD_GRAVITY])
        q = rotations.from_rotvec(np.asarray(rotvec, np.float64).reshape(1, 3))
        return Motion(t, rotations.rotate(np.repeat(q, len(t), 0), acc + g) - g)

    @classmethod
    def none(cls) -> Motion:
        """No accelerometer: the acceleration taken as zero (the filter then keeps the velocity,
        give or take InertialSettings.no_imu_noise)."""
        return cls(np.array([0.0, 1.0]), np.zeros((2, 3)), felt=False)

    @cached_property
    def _integrals(self) -> tuple[FloatArray, FloatArray]:
        dt = np.diff(self.t)[:, None]
        v = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (self.acc[1:] + self.acc[:-1]) * dt, 0)])
        x = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, 0)])
        return v, x

    def integrals(self, tq: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(V (M, 3) m/s, X (M, 3) m) at session times tq (M,) s (module docstring)."""
        tq = np.atleast_1d(np.asarray(tq, np.float64))
        v, x = self._integrals
        inside = np.clip(tq, self.t[0], self.t[-1])
        vq = np.column_stack([np.interp(inside, self.t, v[:, k]) for k in range(3)])
        # V is linear between samples, so X grows by the trapezoid of V from the sample before
        i = np.clip(np.searchsorted(self.t, inside, side="right") - 1, 0, len(self.t) - 1)
        xq = x[i] + 0.5 * (v[i] + vq) * (inside - self.t[i])[:, None]
        xq += vq * (tq - inside)[:, None]  # beyond the samples: no acceleration
        return vq, xq

    def drift(self, t0: npt.ArrayLike, t1: npt.ArrayLike) -> FloatArray:
        """(M, 3) m: how far the acceleration alone moves the platform from t0 to t1 (s, each
        (M,)), from rest: X(t1) - X(t0) - V(t0) (t1 - t0)."""
        t0, t1 = (
            np.atleast_1d(np.asarray(t0, np.float64)),
            np.atleast_1d(np.asarray(t1, np.float64)),
        )
        v0, x0 = self.integrals(t0)
        _, x1 = self.integrals(t1)
        return x1 - x0 - v0 * (t1 - t0)[:, None]

    def jerk(self, tq: npt.ArrayLike, h: float = 0.25) -> FloatArray:
        """(M,) how fast the horizontal acceleration changes (m/s^3) at times tq (s): the
        difference of its means over the h seconds after and before, over h."""
        tq = np.atleast_1d(np.asarray(tq, np.float64))
        before, now, after = (self.integrals(tq + d)[0] for d in (-h, 0.0, h))
        return np.linalg.norm(((after - now) - (now - before))[:, :2], axis=1) / (h * h)


def chained(motion: Motion, t_key: npt.ArrayLike, p_key: npt.ArrayLike, t: float) -> FloatArray:
    """(3,) ENU m: where the registered keyframes (times t_key (K,) s, K >= 2, positions p_key
    (K, 3) m) lead at session time t by the IMU's motion: the position and velocity at the
    first keyframe fitted (least squares) to p_k = p_0 + v_0 (t_k - t_0) + drift(t_0, t_k),
    then carried to t. With no acceleration, constant velocity."""
    tk = np.asarray(t_key, np.float64)
    pk = np.asarray(p_key, np.float64).reshape(-1, 3)
    d = motion.drift(np.full(len(tk), tk[0]), tk)
    a = np.column_stack([np.ones(len(tk)), tk - tk[0]])
    (p0, v0), *_ = np.linalg.lstsq(a, pk - d, rcond=None)
    return p0 + v0 * (t - tk[0]) + motion.drift([tk[0]], [t])[0]


@dataclass(frozen=True)
class Carried:
    """The filter's track at its nodes t (M,) s: position p (M, 3) ENU m, velocity v (M, 3) m/s,
    the GNSS's own error e (M, 3) m (a fix there would say p + e), and the position's
    standard deviation sigma (M, 3) m per axis; felt: an accelerometer drove it (else the
    velocity was only held); said: a line on the video's own motion where it joined, or could
    not (app.register.flow_motion), for the caller to say once."""

    t: FloatArray
    p: FloatArray
    v: FloatArray
    e: FloatArray
    sigma: FloatArray
    felt: bool = True
    said: str = ""  # what the video's own motion did where nothing else measured the track

    def at(self, tq: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(position (Q, 3) ENU m: cubic Hermite between the nodes on their positions and
        velocities, held outside; sigma (Q, 3) m: linear between them) at session times tq."""
        tq = np.clip(np.atleast_1d(np.asarray(tq, np.float64)), self.t[0], self.t[-1])
        i = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self.t) - 2)
        t0, t1 = self.t[i, None], self.t[i + 1, None]
        p = hermite(t0, t1, self.p[i], self.p[i + 1], self.v[i], self.v[i + 1], tq[:, None])
        sigma = np.column_stack([np.interp(tq, self.t, self.sigma[:, k]) for k in range(3)])
        return p, sigma

    def fix_at(self, tq: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(what an honest fix would say (Q, 3) ENU m: the position plus the GNSS's own error,
        the velocity (Q, 3) m/s) at session times tq."""
        tq = np.atleast_1d(np.asarray(tq, np.float64))
        p, _ = self.at(tq)
        e = np.column_stack([np.interp(tq, self.t, self.e[:, k]) for k in range(3)])
        v = np.column_stack([np.interp(tq, self.t, self.v[:, k]) for k in range(3)])
        return p + e, v


@dataclass(frozen=True)
class Drags:
    """The drag-offs among the fixes: lie (N,) the one each fix belongs to (an index into
    steady_s; -1: none), steady_s (L,) from when each one's rate is taken as steady (its
    alarm, session s: it began somewhere between where it was dated and there)."""

    lie: npt.NDArray[np.int64]
    steady_s: FloatArray


@dataclass(frozen=True)
class _Inputs:
    """What the filter runs on: nodes t (M,); per interval k (t[k] -> t[k+1]) the velocity and
    position the acceleration adds (dv, dx (M-1, 3)) and its horizontal jerk (dyn (M-1,) m/s^3);
    per node the fix measured there (fix (M,) index, -1 none), the keyframe (key (M,)) and the
    velocity the video's own motion measured (vel (M,) index into flow: those of
    app.register.flow_motion's inside the nodes' span; None where none was given)."""

    t: FloatArray
    dv: FloatArray
    dx: FloatArray
    dyn: FloatArray
    fix: npt.NDArray[np.int64]
    key: npt.NDArray[np.int64]
    vel: npt.NDArray[np.int64]
    flow: Flow | None = None


def _inputs(
    motion: Motion,
    t_fix: FloatArray,
    t_key: FloatArray,
    settings: InertialSettings,
    span_s: tuple[float, float] | None = None,
    flow: Flow | None = None,
) -> _Inputs:
    ends = np.concatenate([t_fix, t_key, [] if span_s is None else span_s])
    t0, t1 = float(ends.min()), float(ends.max())
    n = max(1, int(np.ceil((t1 - t0) / settings.step_s)))
    flow = None if flow is None else flow.within(t0, t1)
    t_vel = np.zeros(0) if flow is None else flow.t
    t = np.unique(np.concatenate([np.linspace(t0, t1, n + 1), t_fix, t_key, t_vel]))
    v, x = motion.integrals(t)
    dt = np.diff(t)
    dv = np.diff(v, axis=0)
    dx = np.diff(x, axis=0) - v[:-1] * dt[:, None]
    dyn = motion.jerk(0.5 * (t[:-1] + t[1:])) if motion.felt else np.zeros(len(dt))
    fix = np.full(len(t), -1)
    fix[np.searchsorted(t, t_fix)] = np.arange(len(t_fix))
    key = np.full(len(t), -1)
    key[np.searchsorted(t, t_key)] = np.arange(len(t_key))
    vel = np.full(len(t), -1)
    vel[np.searchsorted(t, t_vel)] = np.arange(len(t_vel))
    return _Inputs(t, dv, dx, dyn, fix, key, vel, flow)


def _transition(dt: float, phi: float) -> FloatArray:
    return np.array(
        [
            [1.0, dt, -0.5 * dt * dt, 0.0],
            [0.0, 1.0, -dt, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, phi],
        ]
    )


def _noise(dt: float, q_a: float, q_b: float, gm: FloatArray, phi: float) -> FloatArray:
    """(3, 4, 4) the process noise over dt s: white acceleration q_a (m/s^2/sqrt(Hz)), its
    error's walk q_b (m/s^2/sqrt(s)) integrated into velocity and position, the GNSS error's
    Gauss-Markov step (stationary spread gm (3,) m)."""
    a, b = q_a * q_a, q_b * q_b
    q = np.zeros((4, 4))
    q[0, 0] = a * dt**3 / 3 + b * dt**5 / 20
    q[0, 1] = q[1, 0] = a * dt**2 / 2 + b * dt**4 / 8
    q[0, 2] = q[2, 0] = -b * dt**3 / 6
    q[1, 1] = a * dt + b * dt**3 / 3
    q[1, 2] = q[2, 1] = -b * dt**2 / 2
    q[2, 2] = b * dt
    out = np.repeat(q[None], 3, axis=0)
    out[:, 3, 3] = gm * gm * (1.0 - phi * phi)
    return out


_FIX_H = np.array([1.0, 0.0, 0.0, 1.0])  # a fix: position + the GNSS's own error
_KEY_H = np.array([1.0, 0.0, 0.0, 0.0])  # a keyframe: the position
_VEL_H = np.array([0.0, 1.0, 0.0, 0.0])  # the video's own motion: the velocity
_DRAG_H = np.array([1.0, 0.0, 0.0, 1.0, 1.0, 0.0])  # a dragged fix: + the drag's offset


def _sized(h: FloatArray, n: int) -> FloatArray:
    """h (4,) padded with zeros to the filter's n states (the drag's offset and rate unseen)."""
    return np.concatenate([h, np.zeros(n - len(h))])


def _update(x: FloatArray, p: FloatArray, h: FloatArray, z: FloatArray, r: FloatArray) -> None:
    """Each axis's scalar measurement z (3,) = h x + noise of variance r (3,), in place (Joseph
    form)."""
    s = np.einsum("i,aij,j->a", h, p, h) + r
    k = np.einsum("aij,j->ai", p, h) / s[:, None]
    x += k * (z - x @ h)[:, None]
    ikh = np.eye(len(h))[None] - k[:, :, None] * h[None, None, :]
    p[:] = ikh @ p @ ikh.transpose(0, 2, 1) + r[:, None, None] * k[:, :, None] * k[:, None, :]


class _Filter:
    """The filter's steps over one set of inputs (module docstring): predict from node k-1 to
    node k, update with a fix or a keyframe. State per axis [p, v, b, e]; x (3, 4), P (3, 4, 4);
    where drag_nodes is given, two more: a drag-off's offset and rate [d, w] (its fixes measure
    p + e + d), which start afresh at each node it marks (drag_nodes[0] (M,) bool: offset 0
    give or take twice the fix's accuracy, rate 0 give or take drag_speed0), the rate walking
    by drag_nodes[1] (M,) m/s/sqrt(s) into each node."""

    def __init__(
        self,
        inp: _Inputs,
        fix_sigma: FloatArray,
        felt: bool,
        settings: InertialSettings,
        drag_nodes: tuple[npt.NDArray[np.bool_], FloatArray] | None = None,
    ) -> None:
        self.inp, self.fix_sigma, self.felt, self.s = inp, fix_sigma, felt, settings
        self.drag_nodes = drag_nodes
        self.size = 4 if drag_nodes is None else 6
        # the stated accuracy above the receiver's usual one is taken as white: multipath comes
        # and goes within seconds, and a receiver says so by a larger accuracy
        usual = np.median(fix_sigma, axis=0) if len(fix_sigma) else np.zeros(3)
        extra = np.maximum(fix_sigma**2 - usual**2, 0.0)
        self.white = (settings.white_share * fix_sigma) ** 2 + extra
        # the GNSS error's spread in force at each node: the last fix's stated one
        last = np.maximum.accumulate(np.where(inp.fix >= 0, inp.fix, -1))
        self.gm = (
            fix_sigma[np.maximum(last, 0)]
            if len(fix_sigma)
            else np.full((len(inp.t), 3), settings.accuracy_m)
        )

    def start(self, first_enu: FloatArray | None, anchored: bool) -> tuple[FloatArray, FloatArray]:
        """The state at the first node: at first_enu (3,) m (the first measurement; None:
        none, anywhere), its spread three times the GNSS's, the velocity unknown (v0_sigma; 100
        times that where no fix anchors it)."""
        s = self.s
        x = np.zeros((3, self.size))
        p = np.zeros((3, self.size, self.size))
        sigma0 = self.gm[0]
        p[:, 0, 0] = (3.0 * sigma0) ** 2 + 1.0
        if first_enu is not None:
            x[:, 0] = first_enu
        else:  # nothing measured: anywhere
            p[:, 0, 0] = 1e12
        p[:, 1, 1] = s.v0_sigma**2 * (1.0 if anchored else 100.0)
        p[:, 2, 2] = s.bias0**2 if self.felt else 0.0
        p[:, 3, 3] = sigma0**2
        if self.drag_nodes is not None and self.drag_nodes[0][0]:
            p[:, 4, 4], p[:, 5, 5] = self._drag_spread(0)
        return x, p

    def predict(
        self, x: FloatArray, p: FloatArray, k: int
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(x, P, F) at node k from node k-1's."""
        s, inp = self.s, self.inp
        dt = inp.t[k] - inp.t[k - 1]
        phi = float(np.exp(-dt / s.gnss_tau_s))
        f = _transition(dt, phi)
        q_a = s.acc_noise if self.felt else s.no_imu_noise
        q_b = (s.bias_walk + s.bias_walk_per_jerk * inp.dyn[k - 1]) if self.felt else 0.0
        q = _noise(dt, q_a, q_b, self.gm[k - 1], phi)
        if self.drag_nodes is not None:
            f, q = self._dragged(f, q, dt, k)
        x = x @ f.T
        x[:, 0] += inp.dx[k - 1]
        x[:, 1] += inp.dv[k - 1]
        p = f[None] @ p @ f.T[None] + q
        return x, p, f

    def _dragged(
        self, f: FloatArray, q: FloatArray, dt: float, k: int
    ) -> tuple[FloatArray, FloatArray]:
        """(F (6, 6), Q (3, 6, 6)): f and q with the drag's offset and rate, its offset carried
        on by its rate, which walks; both drawn afresh where a drag-off begins at node k."""
        f6, q6 = np.eye(6), np.zeros((3, 6, 6))
        f6[:4, :4], q6[:, :4, :4] = f, q
        f6[4, 5] = dt
        starts, walk = self.drag_nodes
        w = walk[k] ** 2
        q6[:, 4, 4] += w * dt**3 / 3
        q6[:, 4, 5] += w * dt**2 / 2
        q6[:, 5, 4] += w * dt**2 / 2
        q6[:, 5, 5] += w * dt
        if starts[k]:
            f6[4:, :] = 0.0
            offset, rate = self._drag_spread(k)
            q6[:, 4, 4] += offset
            q6[:, 5, 5] += rate
        return f6, q6

    def _drag_spread(self, k: int) -> tuple[FloatArray, float]:
        """(the offset's variance (3,) m^2, the rate's (m/s)^2) of a drag-off that begins at
        node k: twice the fix's accuracy then, and drag_speed0."""
        return (2.0 * self.gm[k]) ** 2, self.s.drag_speed0**2

    def fix_noise(self, j: int) -> FloatArray:
        """(3,) fix j's white variance per axis (m^2): white_share of its stated accuracy, and
        all of what that exceeds the fixes' median one by."""
        return self.white[j]

    def innovation(
        self, x: FloatArray, p: FloatArray, z: FloatArray, j: int, h: FloatArray = _FIX_H
    ) -> tuple[FloatArray, bool, bool]:
        """(fix j's innovation (3,) m at state x, P (h: what it measures); whether its
        horizontal part (the chi-square of east and north) and its height pass n_sigma)."""
        nu = z - x @ h
        var = np.einsum("i,aij,j->a", h, p, h) + self.fix_noise(j)
        n = self.s.n_sigma
        return (
            nu,
            bool(nu[0] ** 2 / var[0] + nu[1] ** 2 / var[1] > n * n),
            bool(abs(nu[2]) > n * np.sqrt(var[2])),
        )


def _drag_nodes(
    inp: _Inputs, drags: Drags | None, settings: InertialSettings
) -> tuple[npt.NDArray[np.bool_], FloatArray] | None:
    """(the nodes each drag-off begins at (its first fix's) (M,), the walk of its rate into
    each node (M,) m/s/sqrt(s): drag_walk_onset inside a drag before its steady_s, else
    drag_walk) for _Filter; None where no fix is dragged."""
    if drags is None or not (drags.lie >= 0).any():
        return None
    node = np.where(inp.fix >= 0, drags.lie[np.maximum(inp.fix, 0)], -1)
    at = np.flatnonzero(node >= 0)
    starts = np.zeros(len(inp.t), bool)
    starts[at[np.r_[True, node[at][1:] != node[at][:-1]]]] = True
    current = np.maximum.accumulate(np.where(starts, np.arange(len(inp.t)), -1))
    lie = np.where(current >= 0, node[np.maximum(current, 0)], -1)
    onset = (lie >= 0) & (inp.t < drags.steady_s[np.maximum(lie, 0)])
    return starts, np.where(onset, settings.drag_walk_onset, settings.drag_walk)


def _smooth(
    inp: _Inputs,
    fix_enu: FloatArray,
    fix_sigma: FloatArray,
    use: npt.NDArray[np.bool_],
    key_enu: FloatArray,
    felt: bool,
    settings: InertialSettings,
    drags: Drags | None = None,
) -> Carried:
    """The filter forward over the fixes used, the keyframes and the video's own velocities
    (inp.flow), then back (Rauch-Tung-Striebel); drags: the drag-offs' fixes not used, each
    measured with its drag's offset (_Filter) unless it fails the IMU's test (n_sigma)
    against the state before it (the drag left its line)."""
    m = len(inp.t)
    drag = np.full(len(fix_enu), -1) if drags is None else drags.lie
    flt = _Filter(inp, fix_sigma, felt, settings, _drag_nodes(inp, drags, settings))
    fix_h, key_h, vel_h = (_sized(h, flt.size) for h in (_FIX_H, _KEY_H, _VEL_H))
    firsts = [
        (inp.t[k], fix_enu[inp.fix[k]]) for k in range(m) if inp.fix[k] >= 0 and use[inp.fix[k]]
    ][:1]
    firsts += [(inp.t[k], key_enu[inp.key[k]]) for k in range(m) if inp.key[k] >= 0][:1]
    first = min(firsts, key=lambda f: f[0])[1] if firsts else None
    x, p = flt.start(first, anchored=bool(use.any()) or len(key_enu) > 1)
    n = flt.size
    xs_p, ps_p = np.zeros((m, 3, n)), np.zeros((m, 3, n, n))
    xs_f, ps_f = np.zeros((m, 3, n)), np.zeros((m, 3, n, n))
    fs = np.zeros((m, n, n))
    key_r = np.full(3, settings.key_sigma_m**2)
    for k in range(m):
        if k > 0:
            x, p, fs[k - 1] = flt.predict(x, p, k)
        xs_p[k], ps_p[k] = x, p
        j, i, u = inp.fix[k], inp.key[k], inp.vel[k]
        fixed = j >= 0 and use[j]
        on_line = j >= 0 and not fixed and drag[j] >= 0
        if on_line:
            _, off_h, off_v = flt.innovation(x, p, fix_enu[j], j, _DRAG_H)
            on_line = not (off_h or off_v)
        if fixed or on_line or i >= 0 or u >= 0:
            x, p = x.copy(), p.copy()
        if fixed:
            _update(x, p, fix_h, fix_enu[j], flt.fix_noise(j))
        if on_line:
            _update(x, p, _DRAG_H, fix_enu[j], flt.fix_noise(j))
        if i >= 0:
            _update(x, p, key_h, key_enu[i], key_r)
        if u >= 0 and inp.flow is not None:  # horizontal: the height's spread left as it is
            flow = inp.flow
            r = np.array([flow.sigma[u] ** 2, flow.sigma[u] ** 2, 1e12])
            _update(x, p, vel_h, flow.v[u], r)
        xs_f[k], ps_f[k] = x, p
    xs, ps = xs_f.copy(), ps_f.copy()
    # no accelerometer: the acceleration's error is no state (its spread stays 0), so the
    # predicted covariance is singular and only its other states are inverted
    inverse = np.linalg.inv if felt else np.linalg.pinv
    for k in range(m - 2, -1, -1):
        c = ps_f[k] @ fs[k].T[None] @ inverse(ps_p[k + 1])
        xs[k] = xs_f[k] + np.einsum("aij,aj->ai", c, xs[k + 1] - xs_p[k + 1])
        ps[k] = ps_f[k] + c @ (ps[k + 1] - ps_p[k + 1]) @ c.transpose(0, 2, 1)
    sigma = np.sqrt(np.maximum(ps[:, :, 0, 0], 0.0))
    return Carried(inp.t, xs[:, :, 0], xs[:, :, 1], xs[:, :, 3], sigma, felt)


def _screen(
    inp: _Inputs, fix_enu: FloatArray, fix_sigma: FloatArray, settings: InertialSettings
) -> tuple[FloatArray, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """The filter forward over the fixes, each tested before it is used (module docstring)
    against the state one fix before it and against the states windows_s seconds before it
    carried on by the IMU alone (a drag-off that the one-step test lets the filter follow a
    little at a time stands out over a window); a fix that fails is not used, and where a
    window's test fails, the fixes inside that window are taken back too (the filter restarts
    from the window's start, carried by the IMU), and after a fix failed, probation fixes in a
    row must pass before one is used again. Returns (each fix's innovation (N, 3) m against the
    state one fix before it; whether its horizontal part failed, whether its height did (N,)
    each)."""
    flt = _Filter(inp, fix_sigma, True, settings)
    m, n = len(inp.t), len(fix_enu)
    x, p = flt.start(fix_enu[0], anchored=True)
    xs, ps = np.zeros((m, 3, 4)), np.zeros((m, 3, 4, 4))
    innovation = np.full((n, 3), np.nan)
    bad_h = np.zeros(n, bool)
    bad_v = np.zeros(n, bool)
    passed = settings.probation  # fixes passed in a row since the last that failed
    for k in range(m):
        if k > 0:
            x, p, _ = flt.predict(x, p, k)
        j = inp.fix[k]
        if j >= 0:
            fail_from = None  # the earliest node a failed window began at
            tests = [(k, x, p)]
            for w in settings.windows_s:
                a = int(np.searchsorted(inp.t, inp.t[k] - w, side="right")) - 1
                if 0 <= a < k:
                    xa, pa = xs[a], ps[a]
                    for kk in range(a + 1, k + 1):
                        xa, pa, _ = flt.predict(xa, pa, kk)
                    tests.append((a, xa, pa))
            for a, xa, pa in tests:
                nu, h, v = flt.innovation(xa, pa, fix_enu[j], j)
                if a == k:  # the residual said: against the state one fix before
                    innovation[j] = nu
                if h or v:
                    bad_h[j] |= h
                    bad_v[j] |= v
                    if a < k:
                        fail_from = a if fail_from is None else min(fail_from, a)
            if fail_from is not None:  # take the window's fixes back: carry on from its start
                x, p = xs[fail_from], ps[fail_from]
                for kk in range(fail_from + 1, k + 1):
                    x, p, _ = flt.predict(x, p, kk)
            passed = 0 if bad_h[j] or bad_v[j] else passed + 1
            if passed >= settings.probation:
                x, p = x.copy(), p.copy()
                _update(x, p, _FIX_H, fix_enu[j], flt.fix_noise(j))
        xs[k], ps[k] = x, p
    return innovation, bad_h, bad_v


def _sigmas(accuracy_m: npt.ArrayLike | None, n: int, settings: InertialSettings) -> FloatArray:
    """(N, 3) each fix's GNSS spread per axis (m): its stated horizontal accuracy (or
    accuracy_m), v_ratio times that in height."""
    acc = np.full(n, settings.accuracy_m)
    if accuracy_m is not None:
        given = np.asarray(accuracy_m, np.float64)
        acc = np.where(np.isfinite(given) & (given > 0), given, settings.accuracy_m)
    return np.column_stack([acc, acc, settings.v_ratio * acc])


def check_against_imu(
    motion: Motion,
    t_fix: npt.ArrayLike,
    enu_fix: npt.ArrayLike,
    accuracy_m: npt.ArrayLike | None,
    settings: InertialSettings = InertialSettings(),
    check: CheckSettings | None = None,
) -> GnssCheck:
    """The fixes (times t_fix (N,) s, positions enu_fix (N, 3) m, stated horizontal accuracy
    (N,) m or None) tested against the IMU's motion (module docstring): which are rejected,
    the lies (witness `imu`; check: how alarms are merged and lies named, as the scene's test
    does), and each fix's innovation (N, 3) m as its residual. With no accelerometer nothing
    is tested."""
    t = np.asarray(t_fix, np.float64)
    enu = np.asarray(enu_fix, np.float64).reshape(-1, 3)
    residual = np.full((len(t), 3), np.nan)
    if not motion.felt or len(t) < 3:
        return GnssCheck(FixStatus.all_used(t), (), residual)
    inp = _inputs(motion, t, np.zeros(0), settings)
    residual, bad_h, bad_v = _screen(inp, enu, _sigmas(accuracy_m, len(t), settings), settings)
    tested = np.flatnonzero(np.isfinite(residual).all(axis=1))
    # a lie the IMU caught began within its longest window before the alarm
    back_s = max(settings.windows_s, default=0.0) + 1.0
    rejected, lies = lies_of(
        t,
        enu,
        residual,
        tested,
        bad_h[tested],
        bad_v[tested],
        check or CheckSettings(),
        IMU,
        back_s,
    )
    return GnssCheck(FixStatus(t, rejected), tuple(lies), residual)


def carry(
    motion: Motion,
    t_fix: npt.ArrayLike,
    enu_fix: npt.ArrayLike,
    accuracy_m: npt.ArrayLike | None,
    use: npt.ArrayLike,
    t_key: npt.ArrayLike,
    enu_key: npt.ArrayLike,
    settings: InertialSettings = InertialSettings(),
    span_s: tuple[float, float] | None = None,
    flow: Flow | None = None,
    drags: Drags | None = None,
) -> Carried:
    """The track the IMU's motion carries between the fixes used (times t_fix (N,) s,
    positions enu_fix (N, 3) m, stated accuracy (N,) m or None, use (N,) bool) and the
    registered keyframes (times t_key (K,) s, positions enu_key (K, 3) m), forward and back
    (module docstring), over the span of both and span_s (session s); flow: velocities the
    video's own motion measured, where there is no IMU (app.register.flow_motion); drags: the
    drag-offs among the fixes not used (Shifted.drags): their motion less the drag's, a line
    the filter learns from the keyframes and the IMU, carries the track where nothing else
    measures it (_Filter)."""
    t = np.asarray(t_fix, np.float64)
    kt = np.asarray(t_key, np.float64)
    order = np.argsort(kt)
    kt = kt[order]
    kp = np.asarray(enu_key, np.float64).reshape(-1, 3)[order]
    inp = _inputs(motion, t, kt, settings, span_s, flow)
    sig = _sigmas(accuracy_m, len(t), settings)
    enu = np.asarray(enu_fix, np.float64).reshape(-1, 3)
    use = np.asarray(use, bool)
    return _smooth(inp, enu, sig, use, kp, motion.felt, settings, drags)


@dataclass(frozen=True)
class Shifted:
    """The fixes with each steady jump taken back off them: enu (N, 3) ENU m (a jump's fixes
    moved back by its offset, the others as given), use (N,) which of the moved fixes agree
    again (with the IMU's motion, and the keyframes where given) and so stand in the track,
    check: the lies with their `shift` set where they were moved back; drags: the drag-offs
    (`disagrees` lies with no step at their start), indexed as check.lies, their rates steady
    from their alarms (`carry` learns each one's line and carries the track on their fixes'
    motion less it)."""

    enu: FloatArray
    use: npt.NDArray[np.bool_]
    check: GnssCheck
    drags: Drags


def shifted_back(
    motion: Motion,
    t_fix: FloatArray,
    enu_fix: FloatArray,
    accuracy_m: FloatArray | None,
    check: GnssCheck,
    carried: Carried,
    settings: InertialSettings = InertialSettings(),
    t_key: FloatArray | None = None,
    enu_key: FloatArray | None = None,
    lead_s: float = 2.0,
) -> Shifted:
    """A lie that jumped and then holds its offset (a spoofer that moved the whole track, a
    datum or a base-station error) leaves honest fixes behind it: each fix moved back by the
    jump is the position plus the GNSS's own error again. For each `disagrees` lie of check
    whose first fix already stands farther from the track carried over the fixes kept
    (carried, Carried.fix_at: what an honest fix would say, from the fixes before it and the
    keyframes) than the alarm's threshold (a jump: a drag-off starts near it), its offset is
    its first fixes' (over lead_s s) median distance from it (its first seconds only: a
    drag-off may follow);
    its fixes moved back by it are tested again against the IMU's motion and the keyframes
    (t_key (K,) s, enu_key (K, 3) m, where given), and those that pass from its start on,
    until the first that fails (the lie moved on), are used. Times are session s, positions
    ENU m (t_fix (N,), enu_fix (N, 3), accuracy_m (N,) m or None)."""
    t = np.asarray(t_fix, np.float64)
    enu = np.asarray(enu_fix, np.float64).reshape(-1, 3)
    rejected = check.status.rejected
    out, use = enu.copy(), np.zeros(len(t), bool)
    dragged = np.full(len(t), -1)
    steady = np.array([lie.caught_s for lie in check.lies], np.float64)
    sig = _sigmas(accuracy_m, len(t), settings)
    cs = CheckSettings()
    moved: list[tuple[int, npt.NDArray[np.int64], FloatArray]] = []
    for n, lie in enumerate(check.lies):
        idx = np.flatnonzero(rejected & (t >= lie.began_s - 1e-6) & (t <= lie.ended_s + 1e-6))
        if lie.kind != DISAGREES or len(idx) < 3:
            continue
        lead = idx[t[idx] <= t[idx[0]] + lead_s]
        honest, _ = carried.fix_at(t[lead])
        d = np.median(enu[lead] - honest, axis=0)
        h, v = cs.thresholds(np.median(sig[idx, 0]))
        step = enu[lead[0]] - honest[0]  # (its first fix: a drag-off dated late has walked on)
        if np.linalg.norm(step[:2]) <= h and abs(step[2]) <= v:
            dragged[idx] = n  # no step at its start: a drag-off, whose offset does not hold
            continue
        out[idx] = enu[idx] - d
        moved.append((n, idx, d))
    if not moved:
        return Shifted(enu, use, check, Drags(dragged, steady))
    bad = check_against_imu(motion, t, out, accuracy_m, settings).status.rejected
    if t_key is not None and enu_key is not None and len(t_key) >= 2:
        bad = bad | check_fixes(t, out, accuracy_m, t_key, enu_key, cs).status.rejected
    lies = list(check.lies)
    for n, idx, d in moved:
        ok = ~bad[idx]
        early = np.flatnonzero(ok & (t[idx] <= t[idx[0]] + lead_s))  # edge fixes before the jump
        run = idx[:0]
        if len(early):
            first = int(early[0])
            fails = np.flatnonzero(~ok[first:])
            run = idx[first : first + (int(fails[0]) if len(fails) else len(idx))]
        if len(run) < 3:
            run = idx[:0]
        rest = np.setdiff1d(idx, run)
        out[rest] = enu[rest]  # moved back but not used: as given
        if len(run):
            use[run] = True
            lies[n] = replace(lies[n], shift=d, shifted_s=(float(t[run[0]]), float(t[run[-1]])))
    return Shifted(out, use, replace(check, lies=tuple(lies)), Drags(dragged, steady))


def carried_positions(
    fixes: PositionTrack,
    carried: Carried,
    rejected: npt.ArrayLike,
    span_s: tuple[float, float],
    frame: LocalFrame,
) -> PositionTrack:
    """The fixes (a PositionTrack) with the rejected
    ones (N,) replaced by what an honest fix would have said there (Carried.fix_at), and
    each outage between them (app.camera.trajectory.gap_intervals) and beyond them inside
    span_s (the video's session seconds, farther than the gap limit) filled so at the
    carried track's nodes, instead of crossed by a straight line; the others kept, with
    their velocities. frame: the LocalFrame of the ENU positions."""
    rejected = np.asarray(rejected, bool)
    t = fixes.t
    limit = gap_limit_s(t)
    fill = np.zeros(len(carried.t), bool)
    for k in np.flatnonzero(gap_intervals(t)):
        fill |= (carried.t > t[k]) & (carried.t < t[k + 1])
    fill |= (carried.t < t[0]) & (t[0] - span_s[0] > limit) & (carried.t >= span_s[0])
    fill |= (carried.t > t[-1]) & (span_s[1] - t[-1] > limit) & (carried.t <= span_s[1])
    if not rejected.any() and not fill.any():
        return fixes
    moved = np.concatenate([t[rejected], carried.t[fill]])
    honest, vel = carried.fix_at(moved)
    tt = np.concatenate([t[~rejected], moved])
    geo = np.vstack(
        [np.column_stack([fixes.lat, fixes.lon, fixes.h])[~rejected], frame.enu_to_geodetic(honest)]
    )
    v = np.vstack([fixes.vel_enu[~rejected], vel])
    order = np.argsort(tt, kind="stable")
    tt, geo, v = tt[order], geo[order], v[order]
    keep = np.r_[True, np.diff(tt) > 1e-6]
    return PositionTrack.from_fixes(tt[keep], geo[keep, 0], geo[keep, 1], geo[keep, 2], v[keep])


def motion_of(session: Session, poses: PoseTrack, correction: Correction | None = None) -> Motion:
    """The platform's acceleration from the session's accelerometer and the track's device
    attitude, turned world-side by a registration's correction where given (its rotation at
    each attitude sample: the registered attitude, whose tilt the keyframes hold);
    Motion.none() where the session has no accelerometer."""
    if session.acc is None or len(session.acc.t) < 2:
        return Motion.none()
    q = poses.q_device
    if correction is not None and len(correction.t):
        _, dr = correction(poses.t_att)
        q = rotations.multiply(rotations.from_rotvec(dr), q)
    return Motion.of(session.acc.t, session.acc.values, poses.t_att, q)


def _fixes(
    session: Session, track: CameraTrack
) -> tuple[PositionTrack, FloatArray, FloatArray | None]:
    """(the track's fixes, their ENU positions (N, 3) m, their stated accuracy (N,) m or None)."""
    fixes = track.poses.positions
    enu = track.poses.frame.geodetic_to_enu(fixes.lat, fixes.lon, fixes.h)
    acc = session.gnss.h_acc
    return fixes, enu, acc if acc is not None and len(acc) == len(fixes.t) else None


def _video_span(session: Session) -> tuple[float, float]:
    return float(session.frame_times[0]), float(session.frame_times[-1])


@dataclass(frozen=True)
class Screened:
    """The prior before registration, its fixes tested against the IMU: track (the prior,
    its positions carried by the IMU where its fixes were rejected or missing, which its
    `fixes` say), check (the
    IMU's verdict, app.register.gnss.GnssCheck), motion (the acceleration it integrated)."""

    track: CameraTrack
    check: GnssCheck
    motion: Motion


def screened(
    session: Session, prior: CameraTrack, settings: InertialSettings = InertialSettings()
) -> Screened:
    """The prior's fixes tested against the IMU's motion (check_against_imu), and where they
    were rejected or are missing (an outage) its positions carried by that motion between
    the fixes around (carry over the fixes it kept): the start registration searches from,
    which a lie the IMU caught no longer moves. A session without an accelerometer, or with
    nothing rejected or missing, keeps its prior as it was."""
    motion = motion_of(session, prior.poses)
    fixes, enu, acc = _fixes(session, prior)
    check = check_against_imu(motion, fixes.t, enu, acc, settings)
    rejected = check.status.rejected
    if not motion.felt or rejected.all():  # nothing to carry by, or from
        return Screened(prior, check, motion)
    span = _video_span(session)
    carried = carry(motion, fixes.t, enu, acc, ~rejected, [], np.zeros((0, 3)), settings, span)
    back = shifted_back(motion, fixes.t, enu, acc, check, carried, settings)
    if back.use.any():  # a jump's fixes moved back carry the track, and are trusted as fixes
        carried = carry(
            motion,
            fixes.t,
            back.enu,
            acc,
            ~rejected | back.use,
            [],
            np.zeros((0, 3)),
            settings,
            span,
        )
    positions = carried_positions(fixes, carried, rejected, span, prior.poses.frame)
    if positions is fixes:
        return Screened(prior, check, motion)
    poses = replace(prior.poses, positions=positions)
    status = replace(check.status, rejected=rejected & ~back.use)
    return Screened(replace(prior, poses=poses, fixes=status), back.check, motion)


def carried_track(
    session: Session,
    fixes_track: CameraTrack,
    keyframes: list[Keyframe],
    check: GnssCheck,
    correction: Correction,
    settings: InertialSettings = InertialSettings(),
    seen: Seen | None = None,
) -> tuple[PositionTrack, Carried, GnssCheck]:
    """After registration: the track carried by the IMU's motion (under the registered
    attitude, `correction`) over the fixes of fixes_track that `check` kept and the keyframes
    used (module docstring), and without an IMU by the video's own motion where neither
    measures it (app.register.flow_motion); the fixes' positions with the rejected and missing
    ones taken from it (carried_positions; the others as they were); and check with each jump
    whose fixes, moved back by it, were used (shifted_back) said so, and each drag-off whose
    fixes, less its line, carry the track where no keyframe registered (Shifted.drags); seen:
    the corners the video's motion tracked in a solve's earlier carries
    (app.register.flow_motion.Seen)."""
    motion = motion_of(session, fixes_track.poses, correction)
    fixes, enu, acc = _fixes(session, fixes_track)
    span = _video_span(session)
    kept = [k for k in keyframes if k.used]
    kt = np.array([k.time_s for k in kept], np.float64)
    kp = np.array([k.position for k in kept], np.float64).reshape(-1, 3)
    filled = span  # where rejected and missing fixes are filled from the carried track
    if not motion.felt and len(fixes.t):  # no IMU: only between what measured the track
        ends = np.concatenate([fixes.t[[0, -1]], kt[[0, -1]] if len(kt) else []])
        filled = (max(span[0], float(ends.min())), min(span[1], float(ends.max())))
    outages = check.status.outages(*filled) if filled[1] > filled[0] else []
    rejected = check.status.rejected
    used, used_enu, drags = ~rejected, enu, None
    if rejected.any() and (motion.felt or len(kt) >= 2):
        first = carry(motion, fixes.t, enu, acc, used, kt, kp, settings, span)
        back = shifted_back(motion, fixes.t, enu, acc, check, first, settings, kt, kp)
        if back.use.any():
            check, used, used_enu = back.check, ~rejected | back.use, back.enu
        if motion.felt:  # (without an IMU a drag's rate is not told from the platform's own)
            drags = back.drags
            lies = [replace(lie, dragged=bool((drags.lie == n).any())) for n, lie in enumerate(check.lies)]  # fmt: skip
            check = replace(check, lies=tuple(lies))
    flow, said = None, ""
    if not motion.felt and (rejected.any() or outages):
        # no IMU: the video's own motion where nothing measured the track the carry fills
        fixed = (fixes.t[used], used_enu[used])
        flow, said = video_flow(
            session, fixes_track, correction, fixed, (kt, kp), filled, check.status, seen
        )
    # the one carry kept: over the fixes used (some moved back), the keyframes and the flow
    carried = carry(motion, fixes.t, used_enu, acc, used, kt, kp, settings, span, flow, drags)
    carried = replace(carried, said=said)
    if rejected.all() and not len(kt):  # nothing measured it: the fixes as they were
        return fixes, carried, check
    if not motion.felt and not rejected.any() and not outages:
        return fixes, carried, check  # nothing to carry: the fixes as they were
    positions = carried_positions(fixes, carried, rejected, filled, fixes_track.poses.frame)
    return positions, carried, check
