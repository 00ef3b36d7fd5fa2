"""The Earth and rotations on it: WGS84 geodetic <-> ECEF <-> local East-North-Up (enu), the
EGM2008 geoid (geoid), the World Magnetic Model's declination (geomag), and quaternions, the
Euler angles people read and turns about Up (rotations). Float64 numpy, no GL."""

__all__: list[str] = []  # the package exports nothing itself: import its modules
