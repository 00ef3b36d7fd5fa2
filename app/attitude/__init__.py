"""Attitude from inertial sensors and what decides heading.

- `filters`: the paper's gradient-descent and complementary filters (AHRS and IMU forms) and
  the offline forward-backward pass: `estimate(t, gyr, acc, mag, method=...)` (numba kernels in
  `kernels`, the initial orientation in `initial`, the offline passes in `offline`);
- `heading`: where heading comes from (compass anchor, GNSS course), `magcal` the magnetometer's
  calibration on the clip, `gopro` a GoPro's IMU axes, `metrics` the error figures.

The package itself imports none of them, so that commands that need no filter (`geofuse --help`,
`geofuse telemetry`) start without compiling numba kernels.
"""

__all__: list[str] = []  # the package exports nothing itself: import its modules
