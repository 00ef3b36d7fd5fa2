"""Named tolerances and physical constants in one place (units in the names or comments)."""

from __future__ import annotations

# WGS84 ellipsoid
WGS84_A = 6378137.0  # semi-major axis, metres
WGS84_F = 1.0 / 298.257223563  # flattening
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared

# Coordinates whose magnitude exceeds this are taken to be ECEF (metres); a local model is far smaller.
ECEF_MIN_RADIUS_M = 6.0e6

# Time series: a step longer than GAP_FACTOR median steps is a gap (said); between positions, one
# longer than GAP_MIN_S too is crossed by a straight line, not a cubic (no bulge across an outage).
GAP_FACTOR = 5.0
GAP_MIN_S = 5.0
# Horizontal speed (m/s) no phone, car, action camera or small drone reaches: a step between two
# fixes faster than this is a jump (the readers drop a spike and keep a step that holds), and
# positions are not curved across it (no bulge either side of a step kept).
MAX_SPEED_MPS = 150.0
JUMP_SLACK_M = 5.0  # a step must exceed MAX_SPEED_MPS x its time by this too (the fixes' noise)

# Geometry checks
EPS_DEGENERATE = 1e-12  # below this a vector or quaternion norm is treated as zero

# Fields of view cameras have (degrees): a surveillance zoom lens at its longest (real FMV
# reports 0.2-0.4 deg; below 0.01 is no lens) to a wide fisheye; manifests, the CLI and
# Intrinsics refuse others.
FOV_RANGE_DEG = (0.01, 179.0)

# `geofuse sync --write` keeps an offset only above this confidence (the mean correlation of the
# rate components on the fitted windows): the sample walk finds 0.99, a drone's course 0.84-0.91,
# a stabilised GoPro clip 0.00.
SYNC_MIN_CONFIDENCE = 0.5

# A drone clip without gimbal attitude: the camera pitch assumed (degrees above the horizon)
DRONE_DEFAULT_PITCH_DEG = -30.0

# Names of the pose sources that are not filters (app.session.model says what each is)
COURSE = "course"  # the derived source: heading along the track, pitch a setting
TRUTH = "truth"
REGISTERED = "registered"  # a prior source corrected by keyframes registered against the scene
KEYFRAMES_S = 0.5  # `registered`: seconds of video between keyframes (app.register.solve)
# ... for a true orthophoto (`export ortho`): a survey's poses keep the orthophoto within its goal
# (0.13 m median shift against 0.09 m at 0.5 s) at half the registration's time (issue 51)
ORTHO_KEYFRAMES_S = 1.0

# Rendering defaults
DEFAULT_NEAR_M = 0.5  # the video's camera (projector): near and far clipping planes, metres
DEFAULT_FAR_M = 2000.0
VIEW_NEAR_M = 0.3  # the window camera and analysis cameras, which may come closer to surfaces
VIEW_FAR_M = 3000.0
DEFAULT_DEPTH_LONG_SIDE_PX = 2048
DEFAULT_DEPTH_BIAS_M = 0.05  # constant part of the projection depth bias, metres
DEFAULT_DEPTH_SLOPE_BIAS = 2.0  # slope-scaled part, in depth-map texels of surface slope
DEFAULT_ALPHA = 1.0  # video opacity over the model: 0 = model only, 1 = video only

UNIX_TIME_FLOOR_S = 946_684_800.0  # 2000-01-01: session clocks past this are Unix time (UTC)

# A search for the first pose without any GNSS fix (issue 52's cold start): --near without
# --radius, and a live feed's --search-radius around its home point (m).
DEFAULT_START_RADIUS_M = 300.0
